"""Figures of the localization experiment, the seed's Figs. 7-9 plus GOSPA over time."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


def write_localization_figures(
    out_dir: Path,
    results: dict[str, Any],
    trace: dict[str, dict],
    paths: np.ndarray,
    estimates: dict[str, list[np.ndarray]],
) -> None:
    """Write fig7_error_time.png, fig8_weight_sum.png, fig9_paths.png and gospa.png.

    Parameters
    ----------
    trace : per localizer, lists ``time_s``, ``weight_sum``, ``true_count``, ``gospa`` of ugv_0.
    paths : ndarray, shape (T, N, 2)
        World positions of every robot over the first seed.
    estimates : per localizer, T arrays (K_t, 2) of ugv_0's estimates in the world frame.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    names = list(results["localizers"])
    # Fig. 7: per-robot % of time with error > 30 cm, LC vs LO side by side.
    fig, ax = plt.subplots(figsize=(9, 3.5))
    width = 0.8 / len(names)
    for k, name in enumerate(names):
        per_robot = np.asarray(
            results["localizers"][name]["pct_time_err_gt_30cm"]["per_robot"], dtype=float
        )
        ax.bar(np.arange(len(per_robot)) + k * width, np.nan_to_num(per_robot), width, label=name)
    ax.axhline(25, color="k", ls=":", lw=1)
    n_robots = len(results["localizers"][names[0]]["pct_time_err_gt_30cm"]["per_robot"])
    ax.set_xticks(np.arange(n_robots) + 0.4 - width / 2, [str(r) for r in range(n_robots)])
    ax.set_xlabel("robot")
    ax.set_ylabel("% time error > 0.30 m (in range)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out_dir / "fig7_error_time.png", dpi=120)
    plt.close(fig)

    # Fig. 8: sum of weights vs true number of neighbours in range (observer ugv_0).
    fig, ax = plt.subplots(figsize=(9, 3))
    first = trace[names[0]]
    ax.step(first["time_s"], first["true_count"], where="post", color="k", label="true count")
    for name in names:
        ax.plot(trace[name]["time_s"], trace[name]["weight_sum"], lw=1, label=f"{name} sum of w")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("neighbours within range")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out_dir / "fig8_weight_sum.png", dpi=120)
    plt.close(fig)

    # Fig. 9: robot paths and ugv_0's estimates (world frame) for the first localizer.
    fig, ax = plt.subplots(figsize=(6, 6))
    for j in range(paths.shape[1]):
        ax.plot(paths[:, j, 0], paths[:, j, 1], lw=0.8, color="tab:blue" if j else "tab:red")
    pts = [e for e in estimates[names[0]] if len(e)]
    if pts:
        pts = np.concatenate(pts)
        ax.scatter(
            pts[:, 0],
            pts[:, 1],
            marker="x",
            s=4,
            color="k",
            alpha=0.3,
            label=f"ugv_0 estimates ({names[0]})",
        )
        ax.legend(loc="upper right")
    ax.set_aspect("equal")
    ax.set_title("paths (ugv_0 red) and ugv_0's estimates")
    fig.tight_layout()
    fig.savefig(out_dir / "fig9_paths.png", dpi=120)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(9, 3))
    for name in names:
        ax.plot(trace[name]["time_s"], trace[name]["gospa"], lw=1, label=name)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("GOSPA of ugv_0 (m)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out_dir / "gospa.png", dpi=120)
    plt.close(fig)
