"""MkDocs hooks: the generated reference pages of the docs site (``make docs``).

Three pages are written at build time from the code, never by hand, so they cannot drift:

- ``reference/api.md``: the public API, rendered by mkdocstrings from the docstrings of the
  modules in :data:`API_MODULES` (a package's ``__all__`` says what is public).
- ``reference/cli.md``: every ``swarm-phd`` command with its options, defaults and help, walked
  from the argparse parser that ``swarm-phd`` itself builds (:func:`swarm_phd.cli.build_parser`).
- ``reference/config.md``: every field of the configuration dataclasses in
  :data:`CONFIG_CLASSES` (and of the dataclasses they nest) with its type, default, unit and
  description. The convention the page reads:

  * **description**: the class docstring's numpy-style ``Attributes`` section
    (``name : type`` then an indented description; ``a, b : float`` documents both);
  * **unit**: the suffix of the field's name (:data:`UNIT_SUFFIXES`: ``_m`` metres, ``_s``
    seconds, ``_radps`` rad/s...); a field without one is a count, a flag, a name or a
    dimensionless number.

  A field missing from its class's ``Attributes`` section fails the strict build with a
  warning that names the class and the field.

The functions are plain Python (the tests call them); MkDocs calls :func:`on_files`.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import inspect
import logging
import re
import sys
import typing
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:  # the hook is loaded from its file: make the packages importable
    sys.path.insert(0, str(ROOT))

log = logging.getLogger("mkdocs.hooks.reference")

#: The modules of the API page, by package, with what each holds for a user.
API_MODULES: dict[str, list[tuple[str, str]]] = {
    "swarm_env": [
        ("swarm_env", "the PettingZoo parallel env, its presets and configuration"),
        ("swarm_env.tasks", "the tasks (reward, termination, metric) an env runs"),
        ("swarm_env.single_agent", "the single-agent Gymnasium view (`SwarmPHD-v0`)"),
    ],
    "localization": [
        ("localization", "the robot-centric filters and their configuration"),
        ("localization.registry", "the localizer families by name (`--localizer`)"),
        ("localization.metrics", "GOSPA, the error-time statistic and the other scores"),
    ],
    "agents": [
        ("agents.scripted", "the scripted controllers (formation, exploration, encirclement...)"),
        ("agents.policies", "loading a trained or scripted policy from its spec"),
    ],
    "hardware_bridge": [
        ("hardware_bridge", "real robots over rosbridge, recorded bags and the loopback server"),
    ],
    "swarm_core": [
        ("swarm_core.records", "the stamped measurement records (robot body frame, REP-103)"),
        ("swarm_core.world", "the World protocol shared by simulator, robots and bag replay"),
        ("swarm_core.geometry", "angles and planar frames"),
        ("swarm_core.validation", "argument checks whose errors name the field and the value"),
    ],
}

#: The configuration classes of the config page (``module:Class``), in page order. The
#: dataclasses they nest (``SwarmConfig.lidar``...) follow each of them.
CONFIG_CLASSES: list[tuple[str, str]] = [
    (
        "Simulated swarm (`make_config`, `parallel_env(**overrides)`)",
        "swarm_env.config:SwarmConfig",
    ),
    ("Localization: GM-PHD", "localization.config:PHDConfig"),
    ("Localization: PMB", "localization.pmb.config:PMBConfig"),
    ("Localization: ID-PHD (UAV)", "localization.id_phd.config:IDPHDConfig"),
    ("UAV", "swarm_env.uav.config:UAVConfig"),
    ("UAV", "swarm_env.sensors.downward_camera:DownwardCameraConfig"),
    ("Real robots (`hardware_bridge`)", "hardware_bridge.config:BridgeConfig"),
]

#: A field's unit, from the suffix of its name (longest suffix first).
UNIT_SUFFIXES: list[tuple[str, str]] = [
    ("_per_m2", "1/m²"),
    ("_per_m", "1/m"),
    ("_per_rad", "1/rad"),
    ("_per_s", "1/s"),
    ("_per_frame", "per frame"),
    ("_mps2", "m/s²"),
    ("_radps2", "rad/s²"),
    ("_mps", "m/s"),
    ("_radps", "rad/s"),
    ("_mahalanobis2", "squared Mahalanobis distance"),
    ("_m2", "m²"),
    ("_m", "m"),
    ("_ms", "ms"),
    ("_s", "s"),
    ("_deg", "deg"),
    ("_rad", "rad"),
    ("_hz", "Hz"),
    ("_kg", "kg"),
    ("_px", "px"),
    ("_bytes", "bytes"),
    ("_probability", "probability (0-1)"),
    ("_prob", "probability (0-1)"),
    ("_fraction", "fraction (0-1)"),
]

GENERATED_NOTE = (
    "<!-- Generated at build time by tools/docs_hooks.py from the code; do not edit. -->\n\n"
)


# ----------------------------------------------------------------------------------- API


def api_markdown() -> str:
    """The API page: one section per package, one mkdocstrings block per module."""
    out = [
        GENERATED_NOTE,
        "# API reference\n\n",
        "The public Python API, generated from the docstrings. Configuration fields are listed "
        "with their units in the [configuration reference](config.md); the command line in the "
        "[CLI reference](cli.md).\n\n",
        "Layers point down: `swarm_core` < `localization` < `swarm_env` < `hardware_bridge` < "
        "`agents` (see [Architecture](../concepts/architecture.md)).\n\n",
    ]
    for package, modules in API_MODULES.items():
        out.append(f"## `{package}`\n\n")
        for module, what in modules:
            out.append(f"### `{module}`\n\n{what[0].upper() + what[1:]}.\n\n")
            out.append(
                f"::: {module}\n"
                "    options:\n"
                "      show_root_heading: false\n"
                "      show_root_toc_entry: false\n"
                "      heading_level: 4\n\n"
            )
    return "".join(out)


# ----------------------------------------------------------------------------------- CLI


def _md_cell(text: str) -> str:
    """Text safe in a markdown table cell."""
    text = " ".join(str(text).split())
    return text.replace("|", "\\|").replace("<", "&lt;").replace(">", "&gt;")


def _help_text(action: argparse.Action, prog: str) -> str:
    """An action's help with argparse's ``%(default)s``-style fields expanded."""
    if not action.help or action.help is argparse.SUPPRESS:
        return ""
    params = dict(vars(action), prog=prog)
    for name in list(params):
        if params[name] is argparse.SUPPRESS:
            del params[name]
    if params.get("choices") is not None:
        params["choices"] = ", ".join(str(c) for c in params["choices"])
    try:
        return action.help % params
    except (KeyError, TypeError, ValueError):  # a literal % in the help
        return action.help


def _default_text(action: argparse.Action) -> str:
    if isinstance(action, (argparse._HelpAction, argparse._VersionAction)):
        return ""
    if isinstance(action, argparse._StoreTrueAction):
        return "off"
    if isinstance(action, argparse._StoreFalseAction):
        return "on"
    default = action.default
    if default is None or default is argparse.SUPPRESS:
        return ""
    if isinstance(default, (list, tuple)):
        default = " ".join(str(v) for v in default)
    return f"`{default}`"


def _option_name(action: argparse.Action) -> str:
    if action.option_strings:
        if action.nargs == 0:
            return ", ".join(f"`{s}`" for s in action.option_strings)
        metavar = action.metavar or action.dest.upper()
        if isinstance(metavar, tuple):
            metavar = " ".join(metavar)
        return ", ".join(f"`{s} {metavar}`" for s in action.option_strings)
    return f"`{action.metavar or action.dest}`"


def _usage(parser: argparse.ArgumentParser) -> str:
    formatter = argparse.HelpFormatter(parser.prog, width=96)
    formatter.add_usage(parser.usage, parser._actions, parser._mutually_exclusive_groups, "")
    return formatter.format_help().strip()


def _options_table(parser: argparse.ArgumentParser) -> str:
    rows = ["| option | default | description |", "|---|---|---|"]
    for action in parser._actions:
        if action.help is argparse.SUPPRESS or isinstance(action, argparse._SubParsersAction):
            continue
        help_text = _help_text(action, parser.prog)
        if action.choices is not None and "one of" not in help_text:
            choices = ", ".join(str(c) for c in action.choices)
            help_text = f"{help_text}; one of: {choices}" if help_text else f"one of: {choices}"
        rows.append(
            f"| {_option_name(action)} | {_md_cell(_default_text(action))} | "
            f"{_md_cell(help_text)} |"
        )
    return "\n".join(rows) + "\n"


def cli_markdown(parser: argparse.ArgumentParser | None = None) -> str:
    """The CLI page, walked from ``swarm-phd``'s own parser (no subprocess per command)."""
    if parser is None:
        from swarm_phd.cli import build_parser

        parser = build_parser()
    subparsers = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subparsers:
        raise ValueError(f"parser {parser.prog!r} has no subcommands to document")
    commands = subparsers[0].choices
    helps = {a.dest: a.help for a in subparsers[0]._choices_actions}
    out = [
        GENERATED_NOTE,
        "# CLI reference\n\n",
        f"{parser.description}\n\n",
        "Every option's default is shown; `swarm-phd COMMAND --help` prints the same. "
        "Every command also takes `-q/--quiet` (results only, no progress bars) and "
        "`-h/--help`.\n\n",
        "| command | what it does |\n|---|---|\n",
    ]
    for name in commands:
        out.append(f"| [`{name}`](#{_anchor(name)}) | {_md_cell(helps.get(name, ''))} |\n")
    out.append("\n## `swarm-phd`\n\n")
    out.append(f"```text\n{_usage(parser)}\n```\n\n{_options_table(parser)}\n")
    for name, sub in commands.items():
        out.append(f"## `swarm-phd {name}` {{#{_anchor(name)}}}\n\n")
        if sub.description:
            out.append(f"{sub.description[0].upper() + sub.description[1:]}.\n\n")
        out.append(f"```text\n{_usage(sub)}\n```\n\n{_options_table(sub)}\n")
        if sub.epilog:
            out.append(f"{sub.epilog}\n\n")
    return "".join(out)


def _anchor(command: str) -> str:
    return "cmd-" + re.sub(r"[^a-z0-9]+", "-", command.lower())


# -------------------------------------------------------------------------------- config


def _attribute_docs(cls: type) -> dict[str, str]:
    """Field name -> description from the class docstring's numpy ``Attributes`` section."""
    doc = inspect.cleandoc(cls.__doc__ or "")
    match = re.search(r"^Attributes\n-+\n(.*?)(?=^\S.*\n-+\n|\Z)", doc, re.M | re.S)
    if match is None:
        return {}
    docs: dict[str, str] = {}
    names: list[str] = []
    for line in match.group(1).splitlines():
        if line and not line[0].isspace():  # "name, other : type" (or a bare "name")
            head = line.split(" : ", 1)[0].strip().rstrip(":")
            names = [n.strip() for n in head.split(",") if n.strip()]
            for n in names:
                docs[n] = ""
        elif line.strip() and names:
            for n in names:
                docs[n] = f"{docs[n]} {line.strip()}".strip()
    return docs


def unit_of(name: str) -> str:
    """The unit a field's name gives (:data:`UNIT_SUFFIXES`), or ``""``."""
    for suffix, unit in UNIT_SUFFIXES:
        if name.endswith(suffix):
            return unit
    return ""


def _type_text(hint: object) -> str:
    if isinstance(hint, type):
        return hint.__name__
    text = str(hint).replace("typing.", "")
    return re.sub(r"\b(?:[a-z_]+\.)+([A-Z]\w*)", r"\1", text)


def _default_of(f: dataclasses.Field) -> object:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return dataclasses.MISSING


def _default_cell(value: object) -> str:
    if value is dataclasses.MISSING:
        return "required"
    if dataclasses.is_dataclass(value):
        return f"a `{type(value).__name__}`"
    text = repr(value)
    if len(text) > 60:
        text = text[:57] + "..."
    return f"`{text}`"


def _config_table(cls: type, problems: list[str]) -> tuple[str, list[type]]:
    docs = _attribute_docs(cls)
    try:
        hints = typing.get_type_hints(cls)
    except Exception:  # noqa: BLE001  (a hint that does not resolve: show it as written)
        hints = {f.name: f.type for f in dataclasses.fields(cls)}
    rows = ["| field | type | default | unit | what it models |", "|---|---|---|---|---|"]
    nested: list[type] = []
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        default = _default_of(f)
        hint = hints.get(f.name, f.type)
        text = docs.get(f.name, "")
        sub = type(default) if dataclasses.is_dataclass(default) else None
        if sub is None and isinstance(hint, type) and dataclasses.is_dataclass(hint):
            sub = hint
        if sub is not None:
            nested.append(sub)
            link = f"[`{sub.__name__}`](#{sub.__name__.lower()})"
            text = f"{text} (see {link})" if text else f"See {link}."
        elif not text:
            problems.append(f"{cls.__module__}.{cls.__qualname__}.{f.name}")
        rows.append(
            f"| `{f.name}` | {_md_cell(_type_text(hint))} | {_md_cell(_default_cell(default))} "
            f"| {_md_cell(unit_of(f.name))} | {_md_cell(rst_roles_to_md(text))} |"
        )
    return "\n".join(rows) + "\n", nested


def _class_summary(cls: type) -> str:
    doc = inspect.cleandoc(cls.__doc__ or "")
    summary = doc.split("\n\n", 1)[0]
    return rst_roles_to_md(" ".join(summary.split()))


def config_markdown(problems: list[str] | None = None) -> str:
    """The config page; fields missing from their class's ``Attributes`` go to ``problems``."""
    problems = [] if problems is None else problems
    out = [
        GENERATED_NOTE,
        "# Configuration reference\n\n",
        "Every field of the configuration dataclasses, generated from the code. Override a "
        'field by name: `parallel_env(preset, n_robots=8, lidar={"range_max_m": 5.0})`, '
        "`make_config(preset, **overrides)`; an unknown key is refused with its name.\n\n",
        "How to read it: the **unit** is the suffix of the field's name (`_m` metres, `_s` "
        "seconds, `_deg` degrees, `_rad` radians, `_mps` m/s, `_radps` rad/s, `_hz` Hz, "
        "`_per_m2` per square metre...); a field without one is a count, a flag, a name or a "
        "dimensionless number. Angles and frames follow REP-103 (x forward, y left, "
        "counter-clockwise positive). The description is the class docstring's `Attributes` "
        "section.\n\n",
    ]
    done: set[type] = set()
    section = None
    for title, spec in CONFIG_CLASSES:
        module, _, name = spec.partition(":")
        cls = getattr(importlib.import_module(module), name)
        if title != section:
            out.append(f"## {title}\n\n")
            section = title
        queue = [cls]
        while queue:
            current = queue.pop(0)
            if current in done:
                continue
            done.add(current)
            table, nested = _config_table(current, problems)
            out.append(f"### `{current.__name__}`\n\n")
            out.append(
                f"`{current.__module__}.{current.__qualname__}`: {_class_summary(current)}\n\n"
            )
            out.append(table + "\n")
            queue.extend(nested)
    return "".join(out)


# ------------------------------------------------------------------------------- griffe

_ROLE = re.compile(r":(?:py:)?(?:class|func|meth|data|attr|mod|obj|exc|const):`~?([^`]+)`")


def rst_roles_to_md(text: str) -> str:
    """Sphinx roles (``:class:`~a.B` ``) as Markdown code (`` `a.B` ``): the docstrings use
    them; the site shows the name as code without a cross-reference that could dangle."""
    return _ROLE.sub(lambda m: f"`{m.group(1)}`", text)


_PROMPT = re.compile(r"^(\s*)>>> ")


def fence_doctests(text: str) -> str:
    """Wrap interactive examples (``>>>`` lines and their output, up to a blank line) in a
    ``pycon`` fence, so that Markdown shows them as code (their output is not a link)."""
    lines = text.splitlines()
    out: list[str] = []
    i = 0
    while i < len(lines):
        match = _PROMPT.match(lines[i])
        if match is None or (out and out[-1].lstrip().startswith("```")):
            out.append(lines[i])
            i += 1
            continue
        indent = match.group(1)
        block = []
        while i < len(lines) and lines[i].strip():
            block.append(lines[i][len(indent) :] if lines[i].startswith(indent) else lines[i])
            i += 1
        if out and out[-1].strip():
            out.append("")
        out.extend([f"{indent}```pycon", *(indent + b for b in block), f"{indent}```"])
    return "\n".join(out)


try:
    import griffe

    class DoctestFences(griffe.Extension):
        """Griffe extension (``mkdocs.yml``): :func:`fence_doctests` and
        :func:`rst_roles_to_md` on every docstring."""

        def on_instance(self, *, obj, **kwargs) -> None:  # noqa: ANN001, ANN003
            if obj.docstring is None:
                return
            value = rst_roles_to_md(obj.docstring.value)
            if ">>> " in value:
                value = fence_doctests(value)
            obj.docstring.value = value

except ImportError:  # griffe comes with the docs extra; the functions above work without it
    pass


# ------------------------------------------------------------------------------- mkdocs

GENERATED_PAGES = {
    "reference/api.md": api_markdown,
    "reference/cli.md": cli_markdown,
    "reference/config.md": config_markdown,
}


def on_files(files, config):  # noqa: ANN001, ANN201  (MkDocs hook signature)
    """Add the generated reference pages to the site's files."""
    from mkdocs.structure.files import File

    for uri, build in GENERATED_PAGES.items():
        if uri == "reference/config.md":
            problems: list[str] = []
            content = config_markdown(problems)
            for field in problems:
                log.warning(
                    "config field %s has no description: add it to its class docstring's "
                    "Attributes section",
                    field,
                )
        else:
            content = build()
        existing = files.get_file_from_path(uri)
        if existing is not None:
            files.remove(existing)
        files.append(File.generated(config, uri, content=content))
    return files
