"""Per-call cost of PHDBank (batched over robots) against 20 independent RobotCentricPHD.

Realistic states: 20 robots run the same random scenario (8 teammates each, lidar + camera)
until they hold ~20 components; then each call kind is timed on copies of those states:

* predict: all 20 robots (one batch);
* lidar: batches of 3 robots with ~3 points each;
* camera: batches of 12 robots with ~12 bearings each.

Both wall time (``time.perf_counter``) and CPU time (``time.process_time``) are reported, as
the median over repeats. The implied cost per 0.1 s env step uses the env's call mix:
20 predict, 14 lidar, 60 camera updates (= 1 predict batch, ~4.7 lidar, 5 camera batches).

    .venv/bin/python benchmarks/bench_bank.py [--repeats 30]
"""

from __future__ import annotations

import argparse
import copy
import time

import numpy as np

from localization import PHDBank, PHDConfig, RobotCentricPHD

R = 20


def warm_filters(config: PHDConfig, rng: np.random.Generator) -> tuple[list, np.ndarray]:
    filters = [RobotCentricPHD(config) for _ in range(R)]
    targets = rng.uniform(-1.8, 1.8, size=(R, 8, 2))
    for _ in range(40):
        for r, f in enumerate(filters):
            f.predict(rng.normal(0.0, [0.01, 0.003, 0.01]))
            pts = targets[r, rng.choice(8, 4, replace=False)] + rng.normal(0, 0.05, (4, 2))
            f.update_lidar(pts, rng.uniform(-np.pi, np.pi, 2))
            tg = targets[r, rng.integers(0, 8, 12)]
            f.update_camera(np.arctan2(tg[:, 1], tg[:, 0]) + rng.normal(0, 0.08, 12))
    return filters, targets


def make_inputs(rng: np.random.Generator, targets: np.ndarray):
    lidar_batches, camera_batches = [], []
    for _ in range(5):
        rob = rng.choice(R, 3, replace=False)
        pts = [
            targets[r, rng.choice(8, 3, replace=False)] + rng.normal(0, 0.05, (3, 2)) for r in rob
        ]
        nulls = [rng.uniform(-np.pi, np.pi, 2) for _ in rob]
        lidar_batches.append((rob, pts, nulls))
        rob = rng.choice(R, 12, replace=False)
        brg = []
        for r in rob:
            tg = targets[r, rng.integers(0, 8, 12)]
            brg.append(np.arctan2(tg[:, 1], tg[:, 0]) + rng.normal(0, 0.08, 12))
        camera_batches.append((rob, brg))
    odo = rng.normal(0.0, [0.02, 0.005, 0.02], size=(R, 3))
    return odo, lidar_batches, camera_batches


def timed(fn, repeats: int) -> tuple[float, float]:
    walls, cpus = [], []
    for _ in range(repeats):
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
    return float(np.median(walls)), float(np.median(cpus))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--mode", default="lidar-camera")
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    config = PHDConfig(mode=args.mode)
    filters, targets = warm_filters(config, rng)
    odo, lidar_batches, camera_batches = make_inputs(rng, targets)
    print(
        f"components per robot: median {np.median([len(f) for f in filters]):.0f}, "
        f"max {max(len(f) for f in filters)}"
    )

    def per_robot(kind: str):
        fs = [copy.deepcopy(f) for f in filters]

        def run():
            if kind == "predict":
                for f, o in zip(fs, odo, strict=False):
                    f.predict(o)
            elif kind == "lidar":
                for rob, pts, nulls in lidar_batches:
                    for r, p, nb in zip(rob, pts, nulls, strict=False):
                        fs[r].update_lidar(p, nb)
            else:
                for rob, brg in camera_batches:
                    for r, b in zip(rob, brg, strict=False):
                        fs[r].update_camera(b)

        return run

    def banked(kind: str):
        bank = PHDBank.from_filters(filters)
        start = (bank._table.copy(), bank._counts.copy())

        def run():
            bank._table[...] = start[0]  # same starting states every repeat
            bank._counts[...] = start[1]
            if kind == "predict":
                bank.predict(np.arange(R), odo)
            elif kind == "lidar":
                for rob, pts, nulls in lidar_batches:
                    bank.update_lidar(rob, pts, nulls)
            else:
                for rob, brg in camera_batches:
                    bank.update_camera(rob, brg)

        return run

    # calls per timed run: predict 20 robots; lidar 5 batches x 3; camera 5 batches x 12
    per_run = {"predict": (R, 1), "lidar": (15, 5), "camera": (60, 5)}
    per_step = {"predict": 20, "lidar": 14, "camera": 60}  # robot-updates per env step
    x = np.ones(20)
    ref, _ = timed(lambda: x * x, 2000)
    print(f"reference: 20-element numpy multiply {ref * 1e6:.2f} us (machine load indicator)")
    print(
        f"{'call':8s} {'per-robot us/call':>18s} {'bank us/batch':>14s} {'bank us/robot':>14s} "
        f"{'speed-up':>9s}   (wall; cpu)"
    )
    tot = {"filters": [0.0, 0.0], "bank": [0.0, 0.0]}
    for kind in ("predict", "lidar", "camera"):
        n_calls, n_batches = per_run[kind]
        fw, fc = timed(per_robot(kind), args.repeats)
        bw, bc = timed(banked(kind), args.repeats)
        print(
            f"{kind:8s} {fw / n_calls * 1e6:9.1f}; {fc / n_calls * 1e6:6.1f} "
            f"{bw / n_batches * 1e6:8.1f}; {bc / n_batches * 1e6:5.0f} "
            f"{bw / n_calls * 1e6:8.1f}; {bc / n_calls * 1e6:4.1f} "
            f"{fw / bw:6.1f}x; {fc / max(bc, 1e-12):4.1f}x"
        )
        scale = per_step[kind] / n_calls
        tot["filters"][0] += fw * scale
        tot["filters"][1] += fc * scale
        tot["bank"][0] += bw * scale
        tot["bank"][1] += bc * scale
    print("implied PHD cost per env step (20 predict, 14 lidar, 60 camera robot-updates):")
    for name, (w, c) in tot.items():
        print(f"  {name:8s} {w * 1e3:6.2f} ms wall, {c * 1e3:6.2f} ms cpu")
    print(
        f"  speed-up {tot['filters'][0] / tot['bank'][0]:.1f}x wall, "
        f"{tot['filters'][1] / tot['bank'][1]:.1f}x cpu"
    )


if __name__ == "__main__":
    main()
