"""Trained policies shipped with the package: ``pretrained:NAME`` wherever a policy is accepted.

    swarm-phd evaluate --policy pretrained:formation --compare scripted:formation-known-n-fast
    swarm-phd record --policy pretrained:exploration --out exploration.mp4

Each policy lives in its own folder here (``formation/``, ``exploration/``,
``encirclement/``): the policy file a recipe wrote (``student.pt``, or ``model.zip`` with the
run's ``train_config.json`` and ``env_kwargs.json``, so both load weights only, nothing
unpickled) and ``card.json``, its metadata: the recipe (``swarm-phd train --recipe NAME``)
and the commit that trained it, its training and held-out seeds, its held-out scores against
the task's best scripted controller and ``random`` (paired by seed), and whether it meets
the goal of doing at least as well as that controller (``"goal"``; its ``"note"`` says what
limits it where it does not). :func:`card` reads it; ``swarm-phd list`` shows the names.
A policy acts in its own env (the preset, task and observation it was trained in), which
the commands take from its file as for any trained policy.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

__all__ = ["PREFIX", "names", "card", "policy_file", "resolve"]

PREFIX = "pretrained:"
_ROOT = Path(__file__).resolve().parent


def names() -> list[str]:
    """The shipped policies' names (folders with a ``card.json``), sorted."""
    return sorted(p.parent.name for p in _ROOT.glob("*/card.json"))


def card(name: str, flag: str = "--policy") -> dict[str, Any]:
    """The metadata of shipped policy ``name`` (module doc); ``ValueError`` naming ``flag``
    and listing the known names for an unknown one."""
    path = _ROOT / name / "card.json"
    if name not in names():
        known = ", ".join(PREFIX + n for n in names()) or "none"
        raise ValueError(f"{flag}: unknown pretrained policy {PREFIX + name!r}; known: {known}")
    return dict(json.loads(path.read_text()))


def policy_file(name: str, flag: str = "--policy") -> Path:
    """The policy file of shipped policy ``name``."""
    return _ROOT / name / card(name, flag)["policy"]


def resolve(spec: str, flag: str = "--policy") -> str:
    """``spec`` with ``pretrained:NAME`` replaced by the path of that policy's file (other
    specs unchanged); ``ValueError`` naming ``flag`` and listing the known names for an
    unknown one."""
    if isinstance(spec, str) and spec.startswith(PREFIX):
        return str(policy_file(spec[len(PREFIX) :], flag))
    return spec
