"""Checks of the ``swarm-phd`` commands' input that need the env's presets (the others:
:mod:`swarm_core.inputs`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from typing import Any

from swarm_env.config import PRESET_ALIASES, PRESETS, SwarmConfig, make_config


def control_period_s(preset: str, **overrides: Any) -> float:
    """The control period of ``preset`` with its ``SwarmConfig`` overrides (other keys, such as
    ``task_params``, are ignored); ValueError for an unknown preset or a bad override."""
    fields = {f.name for f in dataclasses.fields(SwarmConfig)}
    config = make_config(preset, **{k: v for k, v in overrides.items() if k in fields})
    return config.control_period_s


def known(flag: str, names: Iterable[str]) -> list[str]:
    """``names`` if each is a preset (or an old name of one); else the unknown ones named."""
    names = list(names)
    unknown = [n for n in names if n not in PRESETS and n not in PRESET_ALIASES]
    if unknown:
        raise ValueError(
            f"{flag}: unknown preset(s) {', '.join(map(repr, unknown))}; presets: "
            f"{', '.join(PRESETS)}"
        )
    return names
