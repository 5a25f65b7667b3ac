"""The lidar extractor on scans built without the simulator: housings found and decoys passed.

The scans are the ones of ``tests/hardware_bridge/test_real_scans.py`` (exact ray-cylinder
intersections, 720 beams, 4 mm noise, a square room, blind sectors; each beam whose 0.5 deg
footprint straddles an edge returns, with ``--mixed`` probability, the mean range of its
footprint). Per range: the fraction of housings found (a detection within 4 cm) with the
geometric extent rule (the default) and with the footprint rule (``beam_footprint_deg=0.5``),
the fraction whose scan holds three exact consecutive returns, and the fraction of 120 mm
decoys (front at that range) taken for a housing (within 15 cm), at random bearings outside the
blind sectors.

Usage::

    python benchmarks/bench_real_scans.py --n 400 --mixed 0.5
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from swarm_core.perception.lidar_features import extract_clusters
from tests.hardware_bridge import test_real_scans as scans


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=400, help="targets per range (before blind)")
    parser.add_argument("--mixed", type=float, default=0.5, help="mixed-edge probability")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    print(
        "range m | housings: geometric, footprint, 3 exact returns | decoys: geometric, footprint"
    )
    for r in (0.3, 0.5, 0.8, 1.0, 1.12, 1.5, 2.0, 2.3, 2.45, 2.5, 3.0):
        rng = np.random.default_rng(args.seed)
        out = []
        for radius, tol in ((scans.HOUSING_M, 0.04), (scans.DECOY_M, 0.15)):
            b = rng.uniform(-math.pi, math.pi, args.n)
            b = b[[scans.bearing_clear_of_blind_sectors(x, r, radius) for x in b]]
            # A housing's centre at r (as the filters' range), a decoy's front at r.
            centre = r if radius == scans.HOUSING_M else r + radius
            circles = np.array([[scans.at(centre, x, radius)] for x in b])
            ranges, hit, clean = scans.ray_scans(rng, circles, mixed_prob=args.mixed)
            truth = circles[:, 0, :2]
            for cfg in (scans.REAL, scans.FOOTPRINT_RULE):
                out.append(
                    scans.found(extract_clusters(scans.ANGLES, ranges, cfg), truth, tol).mean()
                )
            if radius == scans.HOUSING_M:
                out.append((scans.longest_clean_run(hit, clean, 0) >= 3).mean())
        print(
            f"{r:7.2f} | "
            + ", ".join(f"{v:6.1%}" for v in out[:3])
            + " | "
            + ", ".join(f"{v:6.1%}" for v in out[3:])
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
