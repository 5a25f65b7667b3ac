"""Round 25's pre-registered test of item 4 (docs/results.md): the margin, then H15.

    python docs/results/round25_noninferiority.py margin
    python docs/results/round25_noninferiority.py test \
        docs/results/results_formation_round25_noninferiority1400.json

``margin`` recomputes the margin from rounds 21-23's tables (seeds 700-849). M1 is
``formation-known-n``'s advantage over ``wander``, per seed. The margin is 0.2 x its one-sided
95 % lower bound: the students keep 80 % of it.

``test`` reads a ``localization_table`` JSON and prints H15's four parts. Every figure is the
table's statistic, the pooled per-observer share of pair-steps above 0.30 m (median observer,
per seed), paired by seed:

- (a) the students' mean per seed, minus ``formation-known-n``'s: mean + 1.96 SE below the
  margin;
- (b) each student better than ``wander`` by more than 2 SE;
- (c) each student's formation error not worse than ``formation-known-n``'s by more than 2 SE;
- (d) each student better than ``anti-symmetry`` by more than 2 SE.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent
STUDENTS = [f"runs/r21/Z_f{f}/student.pt" for f in range(3)]
BASE, WANDER, ANTI = "scripted:formation-known-n", "scripted:wander", "scripted:anti-symmetry"
SHARE = "pooled_per_observer_median_pct"  # the table's "% > 0.30 m", per seed
MARGIN_POINTS = 0.29  # fixed in the pre-registration; ``margin`` shows where it comes from
ROUNDS_21_23 = [
    "results_formation_round21_localization700.json",
    "results_formation_round22_localization750.json",
    "results_formation_round23_localization800.json",
]


def per_seed(table: dict, policy: str, key: str = SHARE) -> np.ndarray:
    """One policy's per-seed figure, in the table's seed order: shape (n_seeds,)."""
    row = next(r for r in table["rows"] if r["policy"] == policy)
    if key == "formation_error_m":  # these rows carry no seed: in the table's seed order
        return np.array([d[key] for d in row["per_seed"]])
    scored = row["localizers"]["phd-lc"]["per_seed"]
    if [d["seed"] for d in scored] != table["seeds"]:
        raise ValueError(f"{policy}: localization seeds differ from the table's")
    return np.array([d[key] for d in scored])


def mean_se(x: np.ndarray) -> tuple[float, float]:
    """Mean and its standard error over seeds."""
    return float(np.mean(x)), float(np.std(x, ddof=1) / np.sqrt(len(x)))


def margin() -> float:
    """0.2 x the one-sided 95 % lower bound of M1 over rounds 21-23's seeds (points)."""
    tables = [json.loads((RESULTS / name).read_text()) for name in ROUNDS_21_23]
    m1 = np.concatenate([per_seed(t, WANDER) - per_seed(t, BASE) for t in tables])
    mean, se = mean_se(m1)
    lower = mean - 1.645 * se
    print(f"M1 (wander - formation-known-n), {len(m1)} seeds: {mean:.3f} points (SE {se:.3f})")
    print(f"one-sided 95 % lower bound {lower:.3f}; margin 0.2 x that = {0.2 * lower:.3f}")
    return 0.2 * lower


def test(path: str) -> bool:
    """Print H15's parts for one table; True when all four hold."""
    table = json.loads(Path(path).read_text())
    n = len(table["seeds"])
    students = np.stack([per_seed(table, s) for s in STUDENTS])  # (3, n_seeds)
    diff_mean, diff_se = mean_se(students.mean(axis=0) - per_seed(table, BASE))
    upper = diff_mean + 1.96 * diff_se
    a = upper < MARGIN_POINTS
    print(f"{n} seeds; the students' mean share minus {BASE}:")
    print(f"  (a) {diff_mean:+.3f} points (SE {diff_se:.3f}), mean + 1.96 SE = {upper:+.3f}")
    print(f"      against the margin {MARGIN_POINTS}: {'met' if a else 'missed'}")
    print(f"      better than scripted (upper bound below 0): {upper < 0}")
    parts = {"a": a}
    checks = [
        ("b", WANDER, SHARE, "better than wander by > 2 SE", lambda m, se: m < -2 * se),
        ("c", BASE, "formation_error_m", "not worse by > 2 SE", lambda m, se: m <= 2 * se),
        ("d", ANTI, SHARE, "better than anti-symmetry by > 2 SE", lambda m, se: m < -2 * se),
    ]
    for part, other, key, what, holds in checks:
        results = []
        for s in STUDENTS:
            m, se = mean_se(per_seed(table, s, key) - per_seed(table, other, key))
            results.append(holds(m, se))
            print(f"  ({part}) {s} - {other}: {m:+.4f} (SE {se:.4f}) {what}: {results[-1]}")
        parts[part] = all(results)
    met = all(parts.values())
    print(f"H15: {'met' if met else 'missed'} ({', '.join(f'{k}={v}' for k, v in parts.items())})")
    return met


if __name__ == "__main__":
    if sys.argv[1:2] == ["margin"]:
        margin()
    elif sys.argv[1:2] == ["test"] and len(sys.argv) == 3:
        sys.exit(0 if test(sys.argv[2]) else 1)  # 1: H15 missed
    else:
        sys.exit(__doc__)
