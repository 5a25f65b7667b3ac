"""Round 26's pre-registered decisive test of item 2 on the PMB (docs/results.md).

    python docs/results/round26_pmb_decisive.py test \
        docs/results/results_formation_round26_pmb_test1700.json

Reads a ``report`` JSON (formation error per seed, m) and prints, paired by seed:

- **H16a, the decision**: round 24c's 80-iteration PPO students, pooled (the mean of the three
  per seed), minus ``formation-known-n-fast`` on the PMB. Met when mean < -2.5 SE.
- **H16b, reported**: the same students minus their DAgger start (round 18's PMB students),
  at the same threshold. With H16a it says whether PPO's own increment is established.
- Robustness, reported and not in the decision: the difference without the seed of largest
  absolute difference, the median, a two-sided sign test, and each fit seed's difference.

The 2.5 SE threshold covers the three earlier looks at these students (docs/results.md,
round 26's pre-registration): under no effect, the chance that this procedure ever declares
item 2 met on the PMB is at most 0.0228**2 + 0.0062 < 0.007.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from scipy.stats import binomtest

METRIC = "formation_error_m"
THRESHOLD_SE = 2.5  # fixed in the pre-registration
BASE = "scripted:formation-known-n-fast"
PPO80 = [f"runs/r24/pmb_F80_f{f}/student.pt" for f in range(3)]
PPO40 = [f"runs/r24/pmb_F_f{f}/student.pt" for f in range(3)]
DAGGER_START = [
    "runs/r18pmb_f0/student_round2.pt",
    "runs/r18pmb_f1/student_round3.pt",
    "runs/r18pmb_f2/student_round3.pt",
]


def per_seed(report: dict, policy: str) -> np.ndarray:
    """One policy's episode formation error per seed, in the report's seed order: (n_seeds,)."""
    scored = report["policies"][policy]
    if scored["seeds"] != report["seeds"]:
        raise ValueError(f"{policy}: its seeds differ from the report's")
    return np.array([episode[METRIC] for episode in scored["per_seed"]])


def pooled(report: dict, policies: list[str]) -> np.ndarray:
    """The mean over a group's policies, per seed: (n_seeds,)."""
    return np.mean([per_seed(report, p) for p in policies], axis=0)


def mean_se(x: np.ndarray) -> tuple[float, float]:
    """Mean and its standard error over seeds."""
    return float(np.mean(x)), float(np.std(x, ddof=1) / np.sqrt(len(x)))


def describe(name: str, diff: np.ndarray, seeds: list[int]) -> bool:
    """Print one paired difference with its robustness figures; True when below -2.5 SE."""
    mean, se = mean_se(diff)
    met = mean < -THRESHOLD_SE * se
    largest = np.argmax(np.abs(diff))
    trimmed_mean, trimmed_se = mean_se(np.delete(diff, largest))
    better = int(np.sum(diff < 0))
    sign_p = binomtest(better, int(np.sum(diff != 0))).pvalue
    print(
        f"{name}: {mean:+.4f} m (SE {se:.4f}, {mean / se:+.2f} SE): {'met' if met else 'missed'}"
    )
    print(
        f"  without its largest |difference| (seed {seeds[largest]}, {diff[largest]:+.4f} m): "
        f"{trimmed_mean:+.4f} m (SE {trimmed_se:.4f}, {trimmed_mean / trimmed_se:+.2f} SE)"
    )
    print(
        f"  median {np.median(diff):+.4f} m; better on {better} of {len(diff)} "
        f"(two-sided sign test p = {sign_p:.4f})"
    )
    return met


def test(path: str) -> bool:
    """Print H16a and H16b for one report; True when H16a, the decision, holds."""
    report = json.loads(Path(path).read_text())
    print(
        f"{len(report['seeds'])} seeds, {report['seeds'][0]}-{report['seeds'][-1]}, "
        f"localizer {report['env_kwargs'].get('localizer')}"
    )
    seeds = report["seeds"]
    ppo80 = pooled(report, PPO80)
    base = per_seed(report, BASE)
    start = pooled(report, DAGGER_START)
    h16a = describe("H16a, 80-iteration students - base", ppo80 - base, seeds)
    h16b = describe("H16b, 80-iteration students - DAgger start", ppo80 - start, seeds)
    print("Reported beside:")
    describe("  40-iteration students - base", pooled(report, PPO40) - base, seeds)
    describe("  DAgger start - base", start - base, seeds)
    for student in PPO80:
        mean, se = mean_se(per_seed(report, student) - base)
        print(f"  {student} - base: {mean:+.4f} m (SE {se:.4f})")
    verdict = "met by PPO" if h16a and h16b else "met by the letter" if h16a else "not met"
    print(f"H16a (decision): {'met' if h16a else 'missed'}; H16b: {'met' if h16b else 'missed'}")
    print(f"Item 2 on the PMB: {verdict}")
    return h16a


if __name__ == "__main__":
    if sys.argv[1:2] == ["test"] and len(sys.argv) == 3:
        sys.exit(0 if test(sys.argv[2]) else 1)  # 1: H16a missed
    sys.exit(__doc__)
