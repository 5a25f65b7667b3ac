"""Measured detection curves of the simulated sensors, and the filter models fitted to them.

What it measures (no timing; every figure is a statistic of the simulated sensors):

* **Lidar** ``P_d(r)``: a teammate's housing at range ``r`` from a scanner, in free space, at a
  random bearing outside the blind sectors, random head phase, no interference (the filter
  has separate blind-sector, occlusion and interference factors, so this is its *range*
  factor). Detected = the feature extractor reports a point within 0.15 m of the housing.
  Also the returns per housing (against ``65 mm / (r x 0.5 deg)``) and the centre error.
* **Lidar false positives on a red decoy**: the same pairs with the housing replaced by a
  lidar-visible cylinder of the arena's ``red_decoy_radius_m`` (60 mm); and, for housings and
  decoys, the rate without the extractor's angular extent test
  (``LidarFeatureConfig.extent_test``).
* **Lidar blind sectors' notch**: the housing at 0.6, 1, 1.5 and 2 m, at random offsets 0-9 deg
  from a random blind sector's centre, no interference; per 1 deg bin the detection rate over
  the full-view rate (20-40 deg off the centres), beside the filter's ``"visible-width"`` factor
  (derived, not fitted: ``docs/concepts/localizers.md``, "The blind sectors' notch") and the
  Perera 2021 study's bump.
* **Camera** ``P_d(r)``: a teammate's red strip (the simulator's ``camera_holder_radius_m``)
  at range ``r``, free line of sight; detected = a blob from that strip. Also the bearing
  error of the detected blobs.
* **Camera clutter** per radian in ``seed-sim`` (the simulator itself: 20 robots wandering in
  random arenas with their red decoys): bearings from red decoys, random false blobs, and
  teammates beyond the lidar's 50 % range (bearings the lidar-initialised filter does not
  track), per frame and per radian. Also the lidar's wide objects (compact clusters wider than
  a housing, ``localization.object_clutter``): per scan, the non-teammate blobs on each per
  frame, their spread about its centre, and the share of the decoys' blobs they explain.

Then fits the Perera 2021 study's sigmoid ``1 / (offset + exp(slope (r - midpoint)))`` (eqs. 19 and
30, ``offset >= 1``) to both measured curves by least squares, and prints them beside the
study's eq. 19 / eq. 30. Writes a JSON (``--json``) and a figure (``--figure``).

Run: ``.venv/bin/python benchmarks/bench_detection_curves.py`` (about a minute).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from scipy.optimize import curve_fit  # noqa: E402

from localization.detection import DetectionModel  # noqa: E402
from localization.object_clutter import wide_objects  # noqa: E402
from localization.scan_memory import scan_profile  # noqa: E402
from swarm_core.perception.lidar_features import extract_clusters  # noqa: E402
from swarm_env.config import SIMULATOR_PHD, make_config  # noqa: E402
from swarm_env.sensors.camera import CameraSensor  # noqa: E402
from swarm_env.sensors.detection_trials import lidar_detects  # noqa: E402
from swarm_env.sensors.lidar import LidarSensor  # noqa: E402
from swarm_env.sensors.scene_builder import HOUSING_RADIUS_M, make_pair_scene  # noqa: E402
from swarm_env.world.sim import SimWorld  # noqa: E402

RANGES_M = np.round(np.arange(0.25, 5.51, 0.125), 3)
WIDTH_EDGES_M = (0.0, 0.08, 0.1, 0.12, 0.14, 0.2, 0.3)  # compact clusters by width
MATCH_GATE_M = 0.15


def seed_sigmoid(r, offset, slope, midpoint):
    """Perera 2021's range factor, eqs. (19) and (30)."""
    return 1.0 / (offset + np.exp(slope * (np.asarray(r) - midpoint)))


SEED_EQ19 = (1.02, 8.0, 1.5)
SEED_EQ30 = (1.1, 5.0, 4.0)


def fit_sigmoid(r: np.ndarray, pd: np.ndarray, guess: tuple[float, float, float]):
    """Least-squares ``(offset, slope, midpoint)`` with ``offset >= 1``; returns also the RMS
    residual."""
    popt, _ = curve_fit(
        seed_sigmoid, r, pd, p0=guess, bounds=([1.0, 0.1, 0.0], [2.0, 100.0, 10.0])
    )
    rms = float(np.sqrt(np.mean((seed_sigmoid(r, *popt) - pd) ** 2)))
    return tuple(float(v) for v in popt), rms


def margin_deg(r: float, radius_m: float = HOUSING_RADIUS_M) -> float:
    """Bearing margin that keeps a whole target of ``radius_m`` at range r (plus a footprint)
    out of a blind sector: the sector is the filter's blind factor, not its range factor."""
    return math.degrees(math.asin(min(radius_m / r, 1.0))) + 1.0


def lidar_curve(cfg, rng, n_pairs: int, target_radius_m: float | None = None) -> dict:
    """Lidar P_d, returns per target and centre error per range.

    The target is a teammate's housing, or with ``target_radius_m`` a lidar-visible cylinder of
    that radius in its place (the arena's red decoy: then ``pd`` is its false-positive rate).
    ``pd_width_only`` is the same scans through the extractor without its angular extent test (the
    rule before 2026-12-02)."""
    lidar_cfg = dataclasses.replace(cfg.lidar, interference_tolerance_deg=0.0)
    radius = HOUSING_RADIUS_M if target_radius_m is None else target_radius_m
    width_only = dataclasses.replace(cfg.lidar_features, extent_test=False)
    out = {
        "target_radius_m": radius,
        "range_m": [],
        "pd": [],
        "pd_width_only": [],
        "returns_mean": [],
        "returns_expected": [],
        "centre_err": [],
    }
    for r in RANGES_M:
        scene, bearings = make_pair_scene(
            rng,
            float(r),
            n_pairs,
            cfg.robot.camera_holder_radius_m,
            lidar_cfg.blind_sector_centers_deg,
            tuple(0.5 * w + margin_deg(r, radius) for w in lidar_cfg.blind_sector_widths_deg),
        )
        if target_radius_m is not None:  # the targets' housings become cylinders of that radius
            target = scene.circle_lidar & (scene.circle_owner % 2 == 1)
            scene = dataclasses.replace(
                scene, circle_radius_m=np.where(target, radius, scene.circle_radius_m)
            )
        sensor = LidarSensor(lidar_cfg, scene.n_robots)
        observers = np.arange(0, scene.n_robots, 2)
        batch = sensor.scan(scene, observers, np.ones(observers.size), rng)
        counts = batch.owner_beam_counts(scene.n_robots)[np.arange(observers.size), observers + 1]
        truth = float(r) * np.stack([np.cos(bearings), np.sin(bearings)], axis=1)
        for key, features in (("pd", cfg.lidar_features), ("pd_width_only", width_only)):
            dets = extract_clusters(batch.angles_rad, batch.ranges_m, features)
            err = np.linalg.norm(dets.xy_m - truth[dets.scan_index], axis=1)
            ok = err <= MATCH_GATE_M
            found = np.zeros(observers.size, dtype=bool)
            found[dets.scan_index[ok]] = True
            out[key].append(float(found.mean()))
            if key == "pd":
                out["centre_err"].append(
                    float(np.sqrt(np.mean(err[ok] ** 2))) if ok.any() else None
                )
        expected = 2.0 * math.asin(min(radius / r, 1.0)) / lidar_cfg.beam_spacing_rad - (
            lidar_cfg.beam_footprint_deg / math.degrees(lidar_cfg.beam_spacing_rad)
        )
        out["range_m"].append(float(r))
        out["returns_mean"].append(float(counts.mean()))
        out["returns_expected"].append(max(expected, 0.0))
    return out


NOTCH_RANGES_M = (0.6, 1.0, 1.5, 2.0)
NOTCH_BINS_DEG = np.arange(0.0, 9.01, 1.0)


def blind_sector_notch(rng, n_pairs: int) -> dict:
    """The lidar's detection rate by offset from a blind sector's centre over its full-view
    rate, per range, beside the filter's notch and the Perera 2021 study's bump (both at the true
    bearing)."""
    notch = DetectionModel(SIMULATOR_PHD)
    bump = DetectionModel(SIMULATOR_PHD.replace(lidar={"blind_sector_model": "seed"}))
    centres = np.asarray(SIMULATOR_PHD.lidar.blind_sector_centers_deg)
    out = {"offset_bins_deg": NOTCH_BINS_DEG.tolist(), "ranges": []}
    for r in NOTCH_RANGES_M:
        offsets = rng.uniform(0.0, 9.0, n_pairs)
        sides = rng.choice(centres, n_pairs) + rng.choice([-1.0, 1.0], n_pairs) * offsets
        in_view = rng.choice(centres, n_pairs // 4) + rng.uniform(20.0, 40.0, n_pairs // 4)
        found = lidar_detects(r, np.radians(np.concatenate((sides, in_view))), rng)
        full_view = float(found[n_pairs:].mean())
        bins = np.digitize(offsets, NOTCH_BINS_DEG) - 1
        at = np.radians(45.0 + offsets)
        ranges = np.full(n_pairs, r)
        models = {"model": notch, "seed_bump": bump}
        row = {"range_m": r, "full_view": full_view, "measured": []}
        row.update({name: [] for name in models})
        factor = {name: m.lidar_blind_sector_factor(at, ranges) for name, m in models.items()}
        for b in range(len(NOTCH_BINS_DEG) - 1):
            sel = bins == b
            row["measured"].append(float(found[:n_pairs][sel].mean()) / max(full_view, 1e-12))
            for name in models:
                row[name].append(float(factor[name][sel].mean()))
        out["ranges"].append(row)
    return out


def camera_curve(cfg, rng, n_pairs: int) -> dict:
    """Camera P_d and bearing error per range, for the simulator's strip radius."""
    camera = CameraSensor(cfg.camera)
    radius = cfg.robot.camera_holder_radius_m
    out = {"range_m": [], "pd": [], "pd_model": [], "bearing_std_deg": []}
    for r in RANGES_M:
        scene, bearings = make_pair_scene(rng, float(r), n_pairs, radius)
        observers = np.arange(0, scene.n_robots, 2)
        batch = camera.observe(scene, observers, rng)
        strip = np.flatnonzero(scene.circle_red)  # strips in robot order
        errs = []
        found = 0
        for k, (bear, src) in enumerate(zip(batch.bearings, batch.sources, strict=True)):
            mine = src == strip[2 * k + 1]
            if mine.any():
                found += 1
                errs.append((bear[mine][0] - bearings[k] + np.pi) % (2 * np.pi) - np.pi)
        out["range_m"].append(float(r))
        out["pd"].append(found / observers.size)
        out["pd_model"].append(float(camera.detection_probability(r, radius)))
        out["bearing_std_deg"].append(
            float(np.degrees(np.sqrt(np.mean(np.square(errs))))) if errs else None
        )
    return out


def fit_bearing_noise(camera: dict, radius_m: float, min_pd: float = 0.9) -> tuple[float, float]:
    """``(constant std deg, width fraction)`` of ``R_C(r) = s0^2 + (k W(r))^2``,
    ``W(r) = 2 asin(R / r)``, least squares on the measured variances per range.

    Only ranges where the camera detects at least ``min_pd`` are used: nearer the edge of its
    range the blob-area test keeps only well-lit blobs, whose centroids sit closer to the
    strip's centre, so the error there is a selected, smaller one."""
    r = np.asarray(camera["range_m"])
    std = np.array([np.nan if s is None else s for s in camera["bearing_std_deg"]])
    keep = (np.asarray(camera["pd"]) >= min_pd) & np.isfinite(std)
    width = np.degrees(2.0 * np.arcsin(np.minimum(1.0, radius_m / r[keep])))
    design = np.stack([np.ones(keep.sum()), width**2], axis=1)
    (a, k2), *_ = np.linalg.lstsq(design, std[keep] ** 2, rcond=None)
    return float(np.sqrt(max(a, 0.0))), float(np.sqrt(max(k2, 0.0)))


def camera_clutter(cfg, seed: int, episodes: int, steps: int, lidar_r50_m: float) -> dict:
    """Non-teammate camera bearings per frame in ``seed-sim`` (the simulator's own arenas), and
    how many of them the lidar places: each robot also scans at the frame's instant, and its
    wide objects (:func:`~swarm_core.perception.lidar_features.extract_wide_objects` on the
    scan's profile, as the filters run it: ``localization.object_clutter.wide_objects``) are
    matched to the blobs within their angular half-width (+ 0.01 rad) of their centre."""
    world = SimWorld(cfg)
    counts = {"frames": 0, "red_decoy": 0, "random": 0, "teammate": 0, "teammate_beyond": 0}
    wide = {"objects": 0, "non_teammate_blobs": 0, "teammate_blobs": 0, "red_decoy_blobs": 0}
    errs, offsets, by_width = [], [], []
    for ep in range(episodes):
        rng = np.random.default_rng(seed + ep)
        world.reset(rng)
        cmd = np.tile([0.2, 0.0], (world.n_agents, 1))
        robots = np.arange(world.n_agents)
        for _ in range(steps):
            cmd[:, 1] = np.clip(cmd[:, 1] + rng.normal(0.0, 0.3, world.n_agents), -1.0, 1.0)
            world.step(cmd)
            poses = world.poses()
            scene = world.scene(poses)
            batch = world.camera.observe(scene, robots, rng)
            scans = world.lidar.scan(scene, robots, np.full(robots.size, world.time_s), rng)
            owner = np.asarray(scene.circle_owner)
            for k, (bear, src) in enumerate(zip(batch.bearings, batch.sources, strict=True)):
                counts["frames"] += 1
                counts["random"] += int((src < 0).sum())
                blobs = src[src >= 0]
                counts["red_decoy"] += int((owner[blobs] < 0).sum())
                mates = blobs[owner[blobs] >= 0]
                counts["teammate"] += mates.size
                d = np.hypot(*(scene.circle_xy[mates] - poses[k, :2]).T)
                counts["teammate_beyond"] += int((d > lidar_r50_m).sum())
                # Bearing error of teammates' blobs at the ranges the arena produces.
                true = np.arctan2(*(scene.circle_xy[mates] - poses[k, :2]).T[::-1]) - poses[k, 2]
                sel = np.isin(src, mates)
                errs.extend(((bear[sel] - true + np.pi) % (2 * np.pi) - np.pi).tolist())
                # Blobs on the scan's wide objects.
                profile = scan_profile(world.lidar.angles_rad, scans.ranges_m[k])
                objects = wide_objects(profile)
                wide["objects"] += objects.shape[0]
                if not objects.shape[0] or not bear.size:
                    continue
                centre = np.arctan2(objects[:, 1], objects[:, 0])
                off = (bear[:, None] - centre[None, :] + np.pi) % (2 * np.pi) - np.pi
                near = np.abs(off) <= objects[None, :, 2] + 0.01
                on = near.any(axis=1)
                mate = np.zeros(bear.size, dtype=bool)
                mate[src >= 0] = owner[src[src >= 0]] >= 0
                decoy = (src >= 0) & ~mate
                wide["non_teammate_blobs"] += int((on & ~mate).sum())
                wide["teammate_blobs"] += int((on & mate).sum())
                wide["red_decoy_blobs"] += int((on & decoy).sum())
                # Per object, by width (all compact clusters up to 0.3 m): which are clutter?
                every = wide_objects(profile, max_width_m=0.3)
                c_all = np.arctan2(every[:, 1], every[:, 0])
                off_all = (bear[:, None] - c_all[None, :] + np.pi) % (2 * np.pi) - np.pi
                near_all = np.abs(off_all) <= every[None, :, 2] + 0.01
                widths = 2.0 * np.hypot(every[:, 0], every[:, 1]) * np.sin(every[:, 2])
                for o in range(every.shape[0]):
                    by_width.append(
                        (widths[o], (near_all[:, o] & ~mate).sum(), (near_all[:, o] & mate).sum())
                    )
                for h in np.flatnonzero(on & ~mate):
                    o = np.argmin(np.abs(off[h]))
                    offsets.append(off[h, o] / objects[o, 2])
    frames = counts["frames"]
    per_frame = {k: v / frames for k, v in counts.items() if k != "frames"}
    table = np.array(by_width, dtype=float).reshape(-1, 3)
    width_bins = []
    for lo, hi in zip(WIDTH_EDGES_M[:-1], WIDTH_EDGES_M[1:], strict=True):
        sel = (table[:, 0] >= lo) & (table[:, 0] < hi)
        width_bins.append(
            {
                "width_m": [lo, hi],
                "objects": int(sel.sum()),
                "non_teammate_blobs_per_object": float(table[sel, 1].mean())
                if sel.any()
                else None,
                "teammate_blobs_per_object": float(table[sel, 2].mean()) if sel.any() else None,
            }
        )
    explained = wide["red_decoy_blobs"] / max(counts["red_decoy"], 1)
    return {
        "frames": frames,
        "per_frame": per_frame,
        "per_rad_false": (per_frame["red_decoy"] + per_frame["random"]) / (2 * np.pi),
        "per_rad_with_untracked": (
            per_frame["red_decoy"] + per_frame["random"] + per_frame["teammate_beyond"]
        )
        / (2 * np.pi),
        "bearing_std_deg_seed_sim": float(np.degrees(np.sqrt(np.mean(np.square(errs))))),
        "lidar_r50_m": lidar_r50_m,
        "wide_objects": {
            **wide,
            "per_scan": wide["objects"] / frames,
            "non_teammate_blobs_per_object": wide["non_teammate_blobs"] / max(wide["objects"], 1),
            "teammate_blobs_per_object": wide["teammate_blobs"] / max(wide["objects"], 1),
            "red_decoy_blobs_explained": explained,
            "offset_std_half_widths": float(np.std(offsets)) if offsets else float("nan"),
            "by_width": width_bins,
            # The uniform rest: decoy blobs no wide object explains, random blobs, teammates
            # beyond the lidar.
            "per_rad_uniform_rest": (
                per_frame["red_decoy"] * (1.0 - explained)
                + per_frame["random"]
                + per_frame["teammate_beyond"]
            )
            / (2 * np.pi),
        },
    }


def crossing(r: np.ndarray, pd: np.ndarray, level: float) -> float:
    """First range where the (decreasing) curve drops below ``level``, linear interpolation."""
    below = np.flatnonzero(pd < level)
    if below.size == 0 or below[0] == 0:
        return float("nan")
    i = below[0]
    return float(r[i - 1] + (pd[i - 1] - level) / (pd[i - 1] - pd[i]) * (r[i] - r[i - 1]))


def _fit_label(fit: tuple[float, float, float]) -> str:
    offset, slope, mid = fit
    return f"fit: 1 / ({offset:.3f} + exp({slope:.2f} (r - {mid:.2f})))"


def plot(lidar, camera, lidar_fit, camera_fit, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fine = np.linspace(0.0, 5.5, 400)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    ax = axes[0]
    ax.plot(lidar["range_m"], lidar["pd"], "o", ms=4, label="simulated (measured)")
    ax.plot(fine, seed_sigmoid(fine, *lidar_fit), "-", label=_fit_label(lidar_fit))
    ax.plot(fine, seed_sigmoid(fine, *SEED_EQ19), "--", label="Perera 2021 eq. 19 (real X4)")
    ax.set_title("Lidar: teammate housing (range factor)")
    ax.set_xlabel("range (m)")
    ax.set_ylabel("detection probability")
    ax.legend(fontsize=8)
    ax = axes[1]
    ax.plot(camera["range_m"], camera["pd"], "o", ms=4, label="simulated (measured)")
    ax.plot(camera["range_m"], camera["pd_model"], ":", label="blob-area model (analytic)")
    ax.plot(fine, seed_sigmoid(fine, *camera_fit), "-", label=_fit_label(camera_fit))
    ax.plot(fine, seed_sigmoid(fine, *SEED_EQ30), "--", label="Perera 2021 eq. 30 (real cameras)")
    ax.set_title("Camera: teammate red strip")
    ax.set_xlabel("range (m)")
    ax.legend(fontsize=8)
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.set_ylim(-0.02, 1.05)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=1500, help="scanner-target pairs per range")
    parser.add_argument("--episodes", type=int, default=5, help="seed-sim episodes (clutter)")
    parser.add_argument("--steps", type=int, default=150, help="env steps per episode")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--figure", type=Path, default=ROOT / "docs/figures/detection_curves.png")
    args = parser.parse_args(argv)
    cfg = make_config("seed-sim")
    rng = np.random.default_rng(args.seed)
    t0 = time.perf_counter()
    lidar = lidar_curve(cfg, rng, args.pairs)
    camera = camera_curve(cfg, rng, args.pairs)
    red_decoy = lidar_curve(cfg, rng, args.pairs, cfg.arena.red_decoy_radius_m)
    notch = blind_sector_notch(rng, args.pairs)
    r = np.asarray(lidar["range_m"])
    lidar_fit, lidar_rms = fit_sigmoid(r, np.asarray(lidar["pd"]), (1.0, 8.0, 2.0))
    camera_fit, camera_rms = fit_sigmoid(r, np.asarray(camera["pd"]), (1.05, 5.0, 4.0))
    r50 = crossing(r, np.asarray(lidar["pd"]), 0.5)
    noise_const_deg, noise_fraction = fit_bearing_noise(camera, cfg.robot.camera_holder_radius_m)
    clutter = camera_clutter(cfg, args.seed, args.episodes, args.steps, r50)

    print(
        f"bench_detection_curves: seed-sim sensors, {args.pairs} pairs per range, "
        f"{platform.machine()}, {time.strftime('%Y-%m-%d')}, {time.perf_counter() - t0:.0f} s"
    )
    print(
        "| range (m) | lidar P_d | Perera 2021 eq. 19 | fit | returns (sim / geometry) "
        "| centre RMS (cm) | camera P_d | blob model | Perera 2021 eq. 30 | fit "
        "| bearing RMS (deg) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for i, rr in enumerate(r):
        if abs(rr * 2 - round(rr * 2)) > 1e-9:  # the table at 0.5 m steps
            continue
        ce = lidar["centre_err"][i]
        bs = camera["bearing_std_deg"][i]
        print(
            f"| {rr:.1f} | {lidar['pd'][i]:.3f} | {seed_sigmoid(rr, *SEED_EQ19):.3f} "
            f"| {seed_sigmoid(rr, *lidar_fit):.3f} "
            f"| {lidar['returns_mean'][i]:.2f} / {lidar['returns_expected'][i]:.2f} "
            f"| {'-' if ce is None else f'{100 * ce:.1f}'} "
            f"| {camera['pd'][i]:.3f} | {camera['pd_model'][i]:.3f} "
            f"| {seed_sigmoid(rr, *SEED_EQ30):.3f} | {seed_sigmoid(rr, *camera_fit):.3f} "
            f"| {'-' if bs is None else f'{bs:.2f}'} |"
        )
    print(
        "\nLidar extractor, angular extent test on / off (the end-to-end width test alone): "
        f"teammate housing P_d and {1000 * red_decoy['target_radius_m']:.0f} mm-radius red decoy "
        "false-positive rate"
    )
    print("| range (m) | housing | housing, width only | red decoy | red decoy, width only |")
    print("|---|---|---|---|---|")
    for i, rr in enumerate(r):
        if abs(rr * 2 - round(rr * 2)) > 1e-9:
            continue
        print(
            f"| {rr:.1f} | {lidar['pd'][i]:.3f} | {lidar['pd_width_only'][i]:.3f} "
            f"| {red_decoy['pd'][i]:.3f} | {red_decoy['pd_width_only'][i]:.3f} |"
        )
    print(
        "\nLidar blind sectors' notch: detection rate over the full-view rate / the filter's "
        "visible-width factor / the Perera 2021 study's bump, by offset from a sector centre"
    )
    print(
        "| range (m) | full view | "
        + " | ".join(f"{lo:.0f}-{lo + 1:.0f} deg" for lo in NOTCH_BINS_DEG[:-1])
        + " |"
    )
    print("|---|---|" + "---|" * (len(NOTCH_BINS_DEG) - 1))
    for row in notch["ranges"]:
        cells = " | ".join(
            f"{m:.2f} / {v:.2f} / {b:.2f}"
            for m, v, b in zip(row["measured"], row["model"], row["seed_bump"], strict=True)
        )
        print(f"| {row['range_m']:.1f} | {row['full_view']:.3f} | {cells} |")
    print(
        "lidar range factor fit (offset, slope /m, midpoint m) = "
        f"({lidar_fit[0]:.4f}, {lidar_fit[1]:.3f}, {lidar_fit[2]:.3f}), RMS residual "
        f"{lidar_rms:.3f}; measured 50 % range {r50:.2f} m"
    )
    print(
        "camera range factor fit (offset, slope /m, midpoint m) = "
        f"({camera_fit[0]:.4f}, {camera_fit[1]:.3f}, {camera_fit[2]:.3f}), RMS residual "
        f"{camera_rms:.3f}"
    )
    print(
        "camera bearing noise fit R_C(r) = s0^2 + (k 2 asin(R / r))^2 (ranges with P_d >= 0.9): "
        f"s0 = {noise_const_deg:.4f} deg, k = {noise_fraction:.4f} (the blob model's "
        f"(1 - fill_min) / 6 = {(1 - cfg.camera.fill_min) / 6:.4f}; pixel rounding alone "
        f"{np.degrees(1 / cfg.camera.pixels_per_rad) / np.sqrt(12):.4f} deg)"
    )
    pf = clutter["per_frame"]
    print(
        f"camera in seed-sim ({clutter['frames']} frames): per frame {pf['red_decoy']:.3f} red "
        f"decoys + {pf['random']:.3f} random = {clutter['per_rad_false']:.4f} /rad false; "
        f"{pf['teammate']:.2f} teammates, {pf['teammate_beyond']:.2f} beyond the lidar's "
        f"{r50:.2f} m -> {clutter['per_rad_with_untracked']:.4f} /rad with them; teammate "
        f"bearing RMS error {clutter['bearing_std_deg_seed_sim']:.3f} deg"
    )
    wo = clutter["wide_objects"]
    print(
        f"wide objects (localization.object_clutter): {wo['per_scan']:.2f} per scan, "
        f"{wo['non_teammate_blobs_per_object']:.3f} non-teammate blobs per object per frame "
        f"({wo['teammate_blobs_per_object']:.3f} teammates'), spread "
        f"{wo['offset_std_half_widths']:.3f} half-widths; they explain "
        f"{100 * wo['red_decoy_blobs_explained']:.0f} % of the red decoys' blobs; uniform rest "
        f"{wo['per_rad_uniform_rest']:.4f} /rad"
    )
    print("| compact cluster width (m) | clusters | non-teammate blobs / frame | teammates' |")
    print("|---|---|---|---|")
    for b in wo["by_width"]:
        if b["objects"]:
            print(
                f"| {b['width_m'][0]:.2f}-{b['width_m'][1]:.2f} | {b['objects']} "
                f"| {b['non_teammate_blobs_per_object']:.3f} "
                f"| {b['teammate_blobs_per_object']:.3f} |"
            )
    if args.figure:
        plot(lidar, camera, lidar_fit, camera_fit, args.figure)
        print(f"figure: {args.figure}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(
            json.dumps(
                {
                    "lidar": lidar,
                    "camera": camera,
                    "red_decoy_lidar": red_decoy,
                    "lidar_blind_sector_notch": notch,
                    "lidar_fit": lidar_fit,
                    "lidar_fit_rms": lidar_rms,
                    "lidar_r50_m": r50,
                    "camera_fit": camera_fit,
                    "camera_fit_rms": camera_rms,
                    "camera_bearing_noise_fit": {
                        "constant_std_deg": noise_const_deg,
                        "width_fraction": noise_fraction,
                    },
                    "camera_clutter": clutter,
                },
                indent=1,
            )
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
