"""The docs: the site builds strict, the runnable docs run, the results page is current, and the
docs tree keeps its shape (no notebook pages, no data files, no study-history wording).

Runnable docs (README.md and docs/getting-started/*.md):

- fenced ```bash blocks hold commands; a command may span lines with a trailing ``\\``; ``#``
  comments are ignored (bash drops them); ``make ...`` lines are not run;
- budgets are shrunk before running (:data:`BUDGETS`): the docs show the real, useful budgets;
- the blocks of one page run in order in one temporary working directory;
- a block preceded by ``<!-- doc-test: skip (reason) -->`` is not run;
- fenced ```python blocks run as scripts in a subprocess (keep each under ~30 s).
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"

#: Budget options rewritten before a documented command runs: option -> what it becomes (a
#: string, or a function of the documented value). The docs show the real, useful budgets;
#: the test only checks that the commands run. ``--n-copies`` / ``--num-cpus`` are the
#: trainer's cost knobs (a rollout of 16 copies in 2 worker processes costs ~20 s more);
#: ``--steps`` is the bridge's episode length.
BUDGETS = {
    "--duration": "2",
    "--timesteps": "128",
    "--seeds": lambda value: re.split(r"[,-]", value)[0],
    "--iterations": "1",
    "--eval-seeds": "1",  # train's final scoring on held-out seeds
    "--n-copies": "2",
    "--num-cpus": "1",
    "--steps": "20",  # swarm-phd bridge runs in real time: 20 steps = 2 s
}
#: Per-block time limits (s).
BASH_TIMEOUT_S = 300
PYTHON_TIMEOUT_S = 120
#: Largest markdown page under docs/ (and README.md).
MAX_PAGE_BYTES = 80_000
#: Data files do not belong under docs/ (figures do).
DATA_SUFFIXES = {
    ".json",
    ".jsonl",
    ".csv",
    ".tsv",
    ".npz",
    ".npy",
    ".pkl",
    ".pickle",
    ".h5",
    ".hdf5",
    ".parquet",
    ".zip",
    ".pt",
}
#: Study-history wording that user-facing text must not carry.
HISTORY_WORDING = re.compile(r"(?<![\w-])(?:issue|round)s?\s+#?\d+", re.IGNORECASE)

SKIP_MARKER = re.compile(r"<!--\s*doc-test:\s*skip\s*\((.+?)\)\s*-->", re.DOTALL)
FENCE = re.compile(r"^(?P<indent>[ \t]*)(?P<fence>`{3,}|~{3,})[ \t]*(?P<lang>[\w+-]*)[^\n]*$")


@dataclass(frozen=True)
class Block:
    """One fenced code block of a page."""

    lang: str
    code: str
    line: int  # 1-based line of the opening fence
    skip: str | None  # the skip marker's reason, or None


def extract_blocks(text: str) -> list[Block]:
    """The fenced blocks of a markdown text, in order, with their skip markers."""
    lines = text.splitlines()
    blocks: list[Block] = []
    i = 0
    while i < len(lines):
        match = FENCE.match(lines[i])
        if match is None:
            i += 1
            continue
        fence, indent = match.group("fence"), match.group("indent")
        start = i
        body: list[str] = []
        i += 1
        while i < len(lines) and not lines[i].strip().startswith(fence):
            line = lines[i]
            body.append(line[len(indent) :] if line.startswith(indent) else line.lstrip())
            i += 1
        i += 1  # the closing fence
        prev = start - 1
        while prev >= 0 and not lines[prev].strip():
            prev -= 1
        skip = None
        if prev >= 0:
            # the marker may span lines: look back to the line that opens the comment
            first = prev
            while first > 0 and "<!--" not in lines[first] and lines[first].strip():
                first -= 1
            marker = SKIP_MARKER.search("\n".join(lines[first : prev + 1]))
            if marker is not None and lines[prev].rstrip().endswith("-->"):
                skip = " ".join(marker.group(1).split())
        blocks.append(Block(match.group("lang").lower(), "\n".join(body), start + 1, skip))
    return blocks


def logical_lines(code: str) -> list[str]:
    """Bash lines with ``\\`` continuations joined."""
    out: list[str] = []
    current = ""
    for line in code.splitlines():
        if line.rstrip().endswith("\\"):
            current += line.rstrip()[:-1] + " "
            continue
        out.append(current + line)
        current = ""
    if current:
        out.append(current)
    return out


def rewrite_budgets(command: str) -> str:
    """``command`` with every budget option of :data:`BUDGETS` shrunk."""
    for option, new in BUDGETS.items():
        pattern = re.compile(
            rf"(?<![\w-]){re.escape(option)}(=|\s+)(\"[^\"]*\"|'[^']*'|[^\s;|&]+)"
        )

        def shrink(match: re.Match, option: str = option, new: object = new) -> str:
            value = match.group(2).strip("'\"")
            return f"{option}{match.group(1)}{new(value) if callable(new) else new}"

        command = pattern.sub(shrink, command)
    return command


def runnable_bash(code: str) -> str:
    """A bash block as the script the harness runs: budgets shrunk, ``make`` lines dropped."""
    kept = []
    for line in logical_lines(code):
        words = line.split()
        if words and words[0] == "make":
            continue
        kept.append(rewrite_budgets(line))
    return "\n".join(kept)


def run_page(path: Path, workdir: Path) -> list[str]:
    """Run a page's bash and python blocks in order in ``workdir``; the skipped ones' reasons."""
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env.setdefault("MPLBACKEND", "Agg")
    env.setdefault("SDL_VIDEODRIVER", "dummy")
    env["PYTHONPATH"] = f"{ROOT}{os.pathsep}{env.get('PYTHONPATH', '')}"
    skipped: list[str] = []
    for n, block in enumerate(extract_blocks(path.read_text(encoding="utf-8"))):
        where = f"{path.name}:{block.line}"
        if block.lang not in ("bash", "sh", "python", "py"):
            continue
        if block.skip is not None:
            skipped.append(f"{where}: {block.skip}")
            continue
        if block.lang in ("bash", "sh"):
            script = runnable_bash(block.code)
            if not script.strip():
                continue
            argv = ["bash", "-e", "-o", "pipefail", "-c", script]
            timeout = BASH_TIMEOUT_S
        else:
            script_path = workdir / f"_doc_block_{n}.py"
            script_path.write_text(block.code + "\n", encoding="utf-8")
            argv = [sys.executable, str(script_path)]
            timeout = PYTHON_TIMEOUT_S
        try:
            result = subprocess.run(
                argv, cwd=workdir, env=env, capture_output=True, text=True, timeout=timeout
            )
        except subprocess.TimeoutExpired:
            pytest.fail(f"{where}: the {block.lang} block ran over {timeout} s:\n{block.code}")
        if result.returncode != 0:
            pytest.fail(
                f"{where}: the {block.lang} block failed (exit {result.returncode}):\n"
                f"{script if block.lang in ('bash', 'sh') else block.code}\n"
                f"--- stdout (tail)\n{result.stdout[-3000:]}\n--- stderr (tail)\n"
                f"{result.stderr[-3000:]}"
            )
    return skipped


def runnable_pages() -> list[Path]:
    pages = [ROOT / "README.md"] + sorted((DOCS / "getting-started").glob("*.md"))
    return [p for p in pages if p.is_file()]


def markdown_pages() -> list[Path]:
    return [ROOT / "README.md"] + sorted(DOCS.rglob("*.md"))


def _load_module(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# ------------------------------------------------------------------ (b) the harness itself

FIXTURE_PAGE = """\
# A page

```bash
# a comment line
python -c "import sys; open('args.txt', 'w').write(' '.join(sys.argv[1:]))" \\
    --duration 300 --timesteps 200000 --seeds 3,4,5 --iterations 40 --eval-duration 60
make demo   # would fail here: make lines are not run
```

Output:

```text
this is not run
exit 1
```

<!-- doc-test: skip (needs real robots) -->
```bash
exit 1
```

<!--
doc-test: skip (spans
two lines)
-->
```bash
false
```

```python
from pathlib import Path

assert Path("args.txt").read_text() == (
    "--duration 2 --timesteps 128 --seeds 3 --iterations 1 --eval-duration 60"
), Path("args.txt").read_text()
Path("python_ran.txt").write_text("yes")
```

```bash
test "$(cat python_ran.txt)" = yes
```
"""


def test_blocks_are_extracted_with_their_skip_markers() -> None:
    blocks = extract_blocks(FIXTURE_PAGE)
    assert [b.lang for b in blocks] == ["bash", "text", "bash", "bash", "python", "bash"]
    assert [b.skip for b in blocks] == [
        None,
        None,
        "needs real robots",
        "spans two lines",
        None,
        None,
    ]
    assert blocks[0].line == 3


def test_budgets_are_shrunk_and_other_options_kept() -> None:
    cmd = (
        "swarm-phd evaluate --duration 300 --seeds 0-19 --localizer phd-lc "
        "--eval-duration 60 --timesteps=3000000 && swarm-phd train --iterations 40"
    )
    assert rewrite_budgets(cmd) == (
        "swarm-phd evaluate --duration 2 --seeds 0 --localizer phd-lc --eval-duration 60 "
        "--timesteps=128 && swarm-phd train --iterations 1"
    )
    assert rewrite_budgets("x --seeds '7,8'") == "x --seeds 7"


def test_continuations_join_and_make_lines_are_dropped() -> None:
    script = runnable_bash("make setup\nswarm-phd demo \\\n  --duration 60\n# note\n")
    lines = script.splitlines()
    assert [line.split() for line in lines] == [
        ["swarm-phd", "demo", "--duration", "2"],
        ["#", "note"],
    ]


def test_fixture_page_runs_in_order_in_one_directory(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text(FIXTURE_PAGE)
    work = tmp_path / "work"
    work.mkdir()
    skipped = run_page(page, work)
    assert skipped == ["page.md:18: needs real robots", "page.md:26: spans two lines"]
    assert (work / "python_ran.txt").read_text() == "yes"


def test_a_failing_block_fails_with_its_location(tmp_path: Path) -> None:
    page = tmp_path / "bad.md"
    page.write_text("# Bad\n\n```bash\necho start\nfalse\n```\n")
    with pytest.raises(pytest.fail.Exception, match=r"bad\.md:3: the bash block failed"):
        run_page(page, tmp_path)


# ------------------------------------------------------------ (b) the real runnable pages


@pytest.mark.slow
@pytest.mark.parametrize("page", runnable_pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_runnable_docs_run(page: Path, tmp_path: Path) -> None:
    run_page(page, tmp_path)


# ----------------------------------------------------------------- (a) the site builds strict


@pytest.mark.slow
def test_site_builds_strict(tmp_path: Path) -> None:
    pytest.importorskip(
        "mkdocs", reason="the docs extra is not installed (pip install -e .[docs])"
    )
    pytest.importorskip("mkdocstrings", reason="the docs extra is not installed")
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "mkdocs",
            "build",
            "--strict",
            "--site-dir",
            str(tmp_path / "site"),
        ],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    warnings = [
        line for line in result.stderr.splitlines() if line.startswith(("WARNING", "ERROR"))
    ]
    assert result.returncode == 0, "mkdocs build --strict failed:\n" + "\n".join(
        warnings or [result.stderr[-5000:]]
    )
    for page in (
        "reference/api/index.html",
        "reference/cli/index.html",
        "reference/config/index.html",
        "results/index.html",
    ):
        assert (tmp_path / "site" / page).is_file(), page


def test_generated_references_cover_the_code() -> None:
    """Every command and option of the CLI, and every field of the swarm's config, appear."""
    hooks = _load_module("docs_hooks", ROOT / "tools" / "docs_hooks.py")
    from swarm_env.config import SwarmConfig
    from swarm_phd.cli import build_parser

    parser = build_parser()
    cli = hooks.cli_markdown(parser)
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    for name, command in sub.choices.items():
        assert f"## `swarm-phd {name}`" in cli, name
        for action in command._actions:
            for option in action.option_strings:
                assert f"`{option}" in cli, (name, option)
    problems: list[str] = []
    config = hooks.config_markdown(problems)
    assert problems == [], f"config fields without a description: {problems}"
    import dataclasses

    for f in dataclasses.fields(SwarmConfig):
        assert f"| `{f.name}` |" in config, f.name
    assert hooks.unit_of("max_turn_rate_radps") == "rad/s"
    assert hooks.unit_of("camera_clutter_per_rad") == "1/rad"
    assert hooks.unit_of("n_robots") == ""


def test_doctests_are_fenced_and_roles_become_code() -> None:
    hooks = _load_module("docs_hooks", ROOT / "tools" / "docs_hooks.py")
    text = "Intro.\n\n>>> sorted(x)[:2]\n['a', 'b']\n\nAfter."
    assert hooks.fence_doctests(text) == (
        "Intro.\n\n```pycon\n>>> sorted(x)[:2]\n['a', 'b']\n```\n\nAfter."
    )
    assert hooks.rst_roles_to_md("see :class:`~localization.PHDConfig`") == (
        "see `localization.PHDConfig`"
    )


# ------------------------------------------------------------ (c) the results page is current


def test_results_page_is_what_the_generator_writes() -> None:
    gen = _load_module("results_page", ROOT / "experiments" / "results_page.py")
    expected = gen.render(gen.load_results())
    assert (DOCS / "results.md").read_text(encoding="utf-8") == expected, (
        "docs/results.md is not what experiments/results_page.py writes: run `make results`"
    )
    assert len(expected.encode()) <= gen.MAX_BYTES


def test_results_generator_refuses_bad_files(tmp_path: Path) -> None:
    gen = _load_module("results_page", ROOT / "experiments" / "results_page.py")
    good = (ROOT / "experiments" / "results" / "env_throughput.json").read_text()
    (tmp_path / "a.json").write_text(good)
    page = gen.render(gen.load_results(tmp_path))
    assert "### How fast does the simulated swarm run" in page
    (tmp_path / "b.json").write_text(good.replace('"commit": "', '"commit": "not a hash '))
    with pytest.raises(ValueError, match=r"b\.json: commit must be a git hash"):
        gen.load_results(tmp_path)
    (tmp_path / "b.json").write_text('{"section": "Throughput"}')
    with pytest.raises(ValueError, match=r"b\.json: missing field\(s\) order, question"):
        gen.load_results(tmp_path)
    out = tmp_path / "page.md"
    (tmp_path / "b.json").unlink()
    assert gen.main(["--results", str(tmp_path), "--out", str(out), "--check"]) == 1
    assert gen.main(["--results", str(tmp_path), "--out", str(out)]) == 0
    assert gen.main(["--results", str(tmp_path), "--out", str(out), "--check"]) == 0


# ------------------------------------------------------------------ (d) the docs tree's shape


def test_no_page_over_the_size_limit() -> None:
    big = {
        str(p.relative_to(ROOT)): p.stat().st_size
        for p in markdown_pages()
        if p.stat().st_size > MAX_PAGE_BYTES
    }
    assert big == {}, f"pages over {MAX_PAGE_BYTES} bytes: {big}"


def test_no_data_files_under_docs() -> None:
    data = [
        str(p.relative_to(ROOT))
        for p in DOCS.rglob("*")
        if p.is_file() and p.suffix.lower() in DATA_SUFFIXES
    ]
    assert data == [], f"data files under docs/ (keep them under experiments/results/): {data}"


def test_no_study_history_wording() -> None:
    found = []
    for page in markdown_pages():
        for n, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1):
            for match in HISTORY_WORDING.finditer(line):
                found.append(f"{page.relative_to(ROOT)}:{n}: {match.group(0)!r}")
    assert found == [], "issue or round numbers in user-facing text:\n" + "\n".join(found[:40])
