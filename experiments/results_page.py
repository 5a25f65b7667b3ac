"""Write the docs site's results page, docs/results.md, from the result files (``make results``).

One row per question the project answers with a figure (throughput, localization accuracy,
learning), each from one JSON file under ``experiments/results/``: the figure, the verdict, the
command that produced it, the commit and date, the machine and where the figure comes from.
The page is generated, never edited by hand: ``tests/test_docs.py`` checks that docs/results.md
is exactly what this script writes from the files.

A result file holds (see ``experiments/results/README.md``)::

    {"section": "Throughput" | "Localization accuracy" | "Learning",
     "order": 1,                      # position within its section
     "question": "...", "headline": "the figure, one line", "verdict": "...",
     "table": {"columns": [...], "rows": [[...], ...]},
     "notes": ["..."],                # optional
     "figure": "figures/x.png",       # optional, relative to docs/
     "command": "...", "commit": "abc1234", "date": "YYYY-MM-DD", "machine": "...",
     "source": "where the figures were taken from",
     "extracted_from": ["git show <commit>:<file>", ...]}  # optional, not shown

Usage::

    python experiments/results_page.py            # writes docs/results.md
    python experiments/results_page.py --check    # exit 1 if docs/results.md is not current
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS_DIR = ROOT / "experiments" / "results"
PAGE = ROOT / "docs" / "results.md"

#: The sections of the page, in order.
SECTIONS = ("Throughput", "Localization accuracy", "Learning")
REQUIRED = (
    "section",
    "order",
    "question",
    "headline",
    "verdict",
    "table",
    "command",
    "commit",
    "date",
    "machine",
    "source",
)
#: The page's size limit (bytes): one current figure per question, not a notebook.
MAX_BYTES = 40_000

_DATE = re.compile(r"^\d{4}-\d{2}-\d{2}$")
_COMMIT = re.compile(r"^[0-9a-f]{7,40}$")


def load_results(results_dir: Path = RESULTS_DIR) -> list[tuple[Path, dict]]:
    """Every result file, checked, in page order (section, then ``order``, then file name)."""
    if not results_dir.is_dir():
        raise ValueError(f"results directory {str(results_dir)!r} does not exist")
    found = []
    for path in sorted(results_dir.glob("*.json")):
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path.name}: not valid JSON ({exc})") from None
        _check(path.name, data)
        found.append((path, data))
    if not found:
        raise ValueError(f"no result files (*.json) in {str(results_dir)!r}")
    return sorted(found, key=lambda f: (SECTIONS.index(f[1]["section"]), f[1]["order"], f[0].name))


def _check(name: str, data: object) -> None:
    if not isinstance(data, dict):
        raise ValueError(
            f"{name}: a result file must hold a JSON object, got {type(data).__name__}"
        )
    missing = [key for key in REQUIRED if key not in data]
    if missing:
        raise ValueError(f"{name}: missing field(s) {', '.join(missing)}")
    if data["section"] not in SECTIONS:
        raise ValueError(f"{name}: section must be one of {SECTIONS}, got {data['section']!r}")
    if isinstance(data["order"], bool) or not isinstance(data["order"], int):
        raise ValueError(f"{name}: order must be an integer, got {data['order']!r}")
    for key in ("question", "headline", "verdict", "command", "machine", "source"):
        if not isinstance(data[key], str) or not data[key].strip():
            raise ValueError(f"{name}: {key} must be a non-empty string, got {data[key]!r}")
    if not isinstance(data["date"], str) or not _DATE.match(data["date"]):
        raise ValueError(f"{name}: date must be YYYY-MM-DD, got {data['date']!r}")
    if not isinstance(data["commit"], str) or not _COMMIT.match(data["commit"]):
        raise ValueError(
            f"{name}: commit must be a git hash (7-40 hex digits), got {data['commit']!r}"
        )
    table = data["table"]
    if not isinstance(table, dict) or not isinstance(table.get("columns"), list):
        raise ValueError(f"{name}: table must be an object with a list of columns, got {table!r}")
    width = len(table["columns"])
    rows = table.get("rows")
    if not isinstance(rows, list) or not rows:
        raise ValueError(f"{name}: table.rows must be a non-empty list, got {rows!r}")
    for i, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != width:
            raise ValueError(
                f"{name}: table.rows[{i}] must be a list of {width} cells, got {row!r}"
            )
    notes = data.get("notes", [])
    if not isinstance(notes, list) or not all(isinstance(n, str) for n in notes):
        raise ValueError(f"{name}: notes must be a list of strings, got {notes!r}")
    figure = data.get("figure")
    if figure is not None and not (ROOT / "docs" / str(figure)).is_file():
        raise ValueError(f"{name}: figure {figure!r} is not a file under docs/")


def _cell(value: object) -> str:
    text = "" if value is None else str(value)
    return " ".join(text.split()).replace("|", "\\|")


def _anchor(path: Path) -> str:
    return path.stem.replace("_", "-")


def _table(columns: list, rows: list) -> str:
    lines = ["| " + " | ".join(_cell(c) for c in columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def render(results: list[tuple[Path, dict]]) -> str:
    """The page's markdown for the loaded result files."""
    out = [
        "<!-- Generated by experiments/results_page.py (`make results`) from "
        "experiments/results/*.json; do not edit. -->\n\n",
        "# Results\n\n",
        "The current figure for each question the project answers with a measurement: one row "
        "per question, the figure, the verdict, and below it the command that produced it, the "
        "commit and date, the machine and the result file it comes from. Figures measured on a "
        "shared 2-core VM drift with its load: compare ratios taken in one run. Terms are "
        "defined in the [glossary](concepts/glossary.md).\n\n",
    ]
    for section in SECTIONS:
        entries = [(p, d) for p, d in results if d["section"] == section]
        if not entries:
            continue
        out.append(f"## {section}\n\n")
        out.append(
            _table(
                ["question", "figure", "verdict"],
                [
                    [f"[{d['question']}](#{_anchor(p)})", d["headline"], d["verdict"]]
                    for p, d in entries
                ],
            )
        )
        out.append("\n")
        for path, d in entries:
            out.append(f"### {d['question']} {{#{_anchor(path)}}}\n\n")
            out.append(f"**{d['headline']}**: {d['verdict']}.\n\n")
            out.append(_table(d["table"]["columns"], d["table"]["rows"]) + "\n")
            for note in d.get("notes", []):
                out.append(f"{note}\n\n")
            if d.get("figure"):
                out.append(f"![{d['question']}]({d['figure']})\n\n")
            out.append(f"- Command: `{d['command']}`\n")
            out.append(f"- Commit {d['commit']}, {d['date']}; {d['machine']}\n")
            out.append(
                f"- File: `experiments/results/{path.name}`; figures from {d['source']}\n\n"
            )
    return "".join(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--results", type=Path, default=RESULTS_DIR, help="result files' directory"
    )
    parser.add_argument("--out", type=Path, default=PAGE, help="the page to write")
    parser.add_argument(
        "--check",
        action="store_true",
        help="write nothing; exit 1 if the page differs from the files' rendering",
    )
    args = parser.parse_args(argv)
    try:
        text = render(load_results(args.results))
    except ValueError as exc:
        print(f"results_page: error: {exc}", file=sys.stderr)
        return 2
    size = len(text.encode("utf-8"))
    if size > MAX_BYTES:
        print(
            f"results_page: error: the page would be {size} bytes, over {MAX_BYTES}",
            file=sys.stderr,
        )
        return 2
    if args.check:
        current = args.out.read_text(encoding="utf-8") if args.out.is_file() else None
        if current != text:
            print(f"{args.out} is not current: run `make results`", file=sys.stderr)
            return 1
        return 0
    args.out.write_text(text, encoding="utf-8")
    print(f"wrote {args.out} ({size} bytes, {text.count('### ')} questions)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
