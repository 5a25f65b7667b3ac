"""Figures of the localization experiment: the Perera 2021 study's Figs. 7-9, plus GOSPA over time.

Inputs are what :func:`swarm_phd.evaluate.evaluate_localization` collects: the per-localizer
:meth:`localization.metrics.SeedScorer.summary` dicts, the scorers' traces of observer
``ugv_0`` (first seed) and the world paths and ``ugv_0``'s estimates (first seed).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

#: Bar colours per localizer (others take matplotlib's cycle).
COLOURS = {"phd-lc": "tab:red", "phd-lo": "tab:blue"}


def _colour(name: str, k: int) -> str:
    return COLOURS.get(name, f"C{k + 2}")


def write_localization_figures(
    out_dir: Path,
    results: dict[str, Any],
    trace: dict[str, dict],
    paths: np.ndarray,
    estimates: dict[str, list[np.ndarray]],
) -> list[Path]:
    """Write fig7_error_time.png, fig8_weight_sum.png, fig9_paths.png and gospa.png.

    Parameters
    ----------
    out_dir : Path
    results : dict
        ``results["localizers"][name]`` is a :meth:`SeedScorer.summary` (``seed_fig7``,
        ``definition``, ...); ``results["config"]`` the run's configuration.
    trace : dict
        Per localizer, :attr:`SeedScorer.trace` of observer ``ugv_0``: lists ``time_s``,
        ``weight_sum_in_range``, ``true_count_in_range``, ``weight_sum_total``,
        ``true_count_total``, ``gospa`` (first seed).
    paths : ndarray, shape (T, N, 2)
        World positions (m) of every robot over the first seed.
    estimates : dict
        Per localizer, T arrays (K_t, 2): ``ugv_0``'s extracted estimates in the world frame (m).

    Returns
    -------
    list of Path
        The files written.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    names = list(results["localizers"])
    cfg = results.get("config", {})
    run = (
        f"{cfg.get('preset', '?')}, {cfg.get('n_robots', '?')} robots, "
        f"{cfg.get('duration_s', 0):.0f} s x {len(cfg.get('seeds', [0]))} seed(s)"
    )
    written = []

    # Fig. 7: one bar per tracked teammate of ugv_0, localizers side by side; on the right,
    # every observer's bars together (the same statistic over the whole swarm).
    fig, (ax, ax_all) = plt.subplots(
        1, 2, figsize=(13, 4.2), gridspec_kw={"width_ratios": [3.2, 1]}
    )
    n_robots = len(results["localizers"][names[0]]["seed_fig7"]["observer_ugv_0"]["per_teammate"])
    teammates = np.arange(1, n_robots)
    width = 0.8 / len(names)
    for k, name in enumerate(names):
        m = results["localizers"][name]
        bars = m["seed_fig7"]["observer_ugv_0"]
        pct = np.asarray(bars["per_teammate"], dtype=float)[teammates]
        x = np.arange(len(teammates)) + (k - (len(names) - 1) / 2) * width
        label = (
            f"{name}: {bars['teammates_above_25pct']} of {bars['tracked_teammates']} tracked "
            f"above 25 %, median {bars['median']:.1f} %"
        )
        ax.bar(x, np.nan_to_num(pct), width, color=_colour(name, k), label=label)
        untracked = ~np.isfinite(pct)
        if untracked.any():  # never in range: no bar, marked on the axis
            ax.plot(x[untracked], np.zeros(untracked.sum()), "x", color="k", ms=5)
    ax.axhline(25, color="k", ls=":", lw=1, label="25 % (Perera 2021's count threshold)")
    ax.set_xticks(np.arange(len(teammates)), [f"{j}" for j in teammates])
    ax.set_xlabel("teammate ugv_j of observer ugv_0 (x: never in range; no x, no bar: 0 %)")
    ax.set_ylabel("% of in-range time with error > 0.30 m")
    range_m = results["localizers"][names[0]]["definition"]["in_range_m"]
    ax.set_title(
        f"Fig. 7: ugv_0's error > 0.30 m per teammate (closest component with w > 0.1; "
        f"in range = within {range_m:.1f} m)\n{run}",
        fontsize=10,
    )
    ax.set_ylim(0, 100)
    ax.legend(fontsize=8, loc="upper right")
    edges = np.linspace(0, 100, 21)
    for k, name in enumerate(names):
        m = results["localizers"][name]["seed_fig7"]["all_observers"]
        ax_all.hist(
            np.asarray(m["per_pair"], dtype=float),
            bins=edges,
            histtype="step",
            lw=1.5,
            color=_colour(name, k),
            label=f"{name}: {m['pairs_above_25pct']} of {m['tracked_pairs']} > 25 %, "
            f"median {m['median']:.1f} %",
        )
    ax_all.axvline(25, color="k", ls=":", lw=1)
    ax_all.set_yscale("log")
    ax_all.set_xlabel("% of in-range time with error > 0.30 m")
    ax_all.set_ylabel("tracked (observer, teammate) pairs")
    ax_all.set_title("every observer's bars", fontsize=10)
    ax_all.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    written.append(out_dir / "fig7_error_time.png")
    fig.savefig(written[-1], dpi=120)
    plt.close(fig)

    # Fig. 8: weight sums against true counts, whole mixture and within range (ugv_0).
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 5.5), sharex=True)
    first = trace[names[0]]
    top.step(
        first["time_s"], first["true_count_total"], where="post", color="k", label="true teammates"
    )
    bottom.step(
        first["time_s"],
        first["true_count_in_range"],
        where="post",
        color="k",
        label=f"true teammates within {range_m:.1f} m",
    )
    for k, name in enumerate(names):
        t = trace[name]
        top.plot(t["time_s"], t["weight_sum_total"], lw=0.8, color=_colour(name, k), label=name)
        bottom.plot(
            t["time_s"], t["weight_sum_in_range"], lw=0.8, color=_colour(name, k), label=name
        )
    top.set_ylabel("whole-mixture sum of w\n(teammates)")
    bottom.set_ylabel(f"sum of w within {range_m:.1f} m\n(teammates)")
    bottom.set_xlabel("time (s)")
    top.set_title(
        f"Fig. 8: ugv_0's expected number of teammates (sum of weights) vs truth, "
        f"first seed\n{run}",
        fontsize=10,
    )
    top.legend(fontsize=8, loc="upper right")
    bottom.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    written.append(out_dir / "fig8_weight_sum.png")
    fig.savefig(written[-1], dpi=120)
    plt.close(fig)

    # Fig. 9: paths and ugv_0's estimates in the world frame, one panel per localizer.
    fig, axes = plt.subplots(
        1, len(names), figsize=(5.5 * len(names), 5.5), squeeze=False, sharex=True, sharey=True
    )
    for ax, name in zip(axes[0], names, strict=True):
        for j in range(paths.shape[1]):
            ax.plot(
                paths[:, j, 0],
                paths[:, j, 1],
                lw=1.2 if j == 0 else 0.6,
                color="tab:red" if j == 0 else "tab:blue",
                alpha=1.0 if j == 0 else 0.6,
                label="ugv_0 (observer)" if j == 0 else ("teammates" if j == 1 else None),
            )
        pts = [e for e in estimates[name] if len(e)]
        if pts:
            pts = np.concatenate(pts)
            ax.scatter(
                pts[:, 0], pts[:, 1], marker="x", s=3, color="k", alpha=0.25, lw=0.5,
                label="ugv_0's estimates (w >= 0.5)",
            )  # fmt: skip
        ax.set_aspect("equal")
        ax.set_xlabel("x (m, world)")
        ax.set_ylabel("y (m, world)")
        ax.set_title(f"Fig. 9: paths and ugv_0's estimates, {name}", fontsize=10)
        ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    written.append(out_dir / "fig9_paths.png")
    fig.savefig(written[-1], dpi=120)
    plt.close(fig)

    # GOSPA of ugv_0 over time.
    fig, ax = plt.subplots(figsize=(10, 3))
    for k, name in enumerate(names):
        g = results["localizers"][name]["gospa"]
        ax.plot(
            trace[name]["time_s"],
            trace[name]["gospa"],
            lw=0.8,
            color=_colour(name, k),
            label=f"{name} (all observers' mean {g['mean_m']:.3f} m)",
        )
    ax.set_xlabel("time (s)")
    ax.set_ylabel("GOSPA of ugv_0 (m)")
    g = results["localizers"][names[0]]["gospa"]
    ax.set_title(
        f"GOSPA (c = {g['c_m']:g} m, p = {g['p']:g}, alpha = {g['alpha']:g}) of ugv_0, "
        f"teammates within {range_m:.1f} m vs estimates (w >= 0.5) within {range_m:.1f} m",
        fontsize=10,
    )
    ax.legend(fontsize=8)
    fig.tight_layout()
    written.append(out_dir / "gospa.png")
    fig.savefig(written[-1], dpi=120)
    plt.close(fig)
    return written
