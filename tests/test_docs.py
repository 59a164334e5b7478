"""The documentation cannot rot: every ```python block of README.md and docs/**/*.md runs, every
relative link (and its #anchor) points at something that exists, every page is reachable from
README.md and in the site's nav, the site builds with warnings as errors, and the front door's
docstring examples run. Bash blocks are not run."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path
from typing import NamedTuple

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
PYTHON = {"python", "py", "python3"}
TIMEOUT_S = 120  # a guard against a hang; the blocks take seconds

FENCE = re.compile(r"^(\s*)(`{3,}|~{3,})\s*([\w+-]*)")


class Block(NamedTuple):
    page: Path
    line: int  # 1-based line of the opening fence
    end: int  # 1-based line of the closing fence (the last line if unclosed)
    lang: str
    code: str


def blocks(page: Path) -> list[Block]:
    """The fenced code blocks of a page (an unclosed fence runs to the end of the page, as in
    CommonMark)."""
    lines = page.read_text(encoding="utf-8").splitlines()
    found, i = [], 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        indent, fence, lang = m.group(1), m.group(2), m.group(3).lower()
        j, body = i + 1, []
        while j < len(lines) and not re.match(
            rf"^\s*{re.escape(fence[0])}{{{len(fence)},}}\s*$", lines[j]
        ):
            body.append(
                lines[j][len(indent) :] if lines[j].startswith(indent) else lines[j].lstrip()
            )
            j += 1
        found.append(Block(page, i + 1, min(j + 1, len(lines)), lang, "\n".join(body) + "\n"))
        i = j + 1
    return found


ALL_BLOCKS = [b for page in PAGES for b in blocks(page)]
PYTHON_BLOCKS = [b for b in ALL_BLOCKS if b.lang in PYTHON]


def block_id(b: Block) -> str:
    return f"{b.page.relative_to(ROOT)}:{b.line}"


def test_pages_exist():
    assert (ROOT / "README.md").is_file()
    assert len(PAGES) > 1, "docs/**/*.md: no pages"


def test_there_are_python_blocks_to_run():
    """The docs do show code (the library's example); the test below is not vacuous."""
    assert PYTHON_BLOCKS


# a block that registers a component runs in a process of its own: the registries are global, and
# the other blocks (and tests) in this process would see it
REGISTERS = re.compile(r"\.register\(")


@pytest.mark.parametrize("block", PYTHON_BLOCKS, ids=block_id)
def test_python_block_runs(block: Block, monkeypatch):
    """Each block runs as a reader pastes it: from the repository root, in a fresh namespace, in
    this process (set up as the block's own configure_jax() sets it up); a block that registers a
    component in a process of its own."""
    if REGISTERS.search(block.code):
        _run_in_own_process(block)
        return
    monkeypatch.chdir(ROOT)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    try:
        exec(compile(block.code, block_id(block), "exec"), {"__name__": "__main__"})
    except Exception as error:
        pytest.fail(f"{block_id(block)} failed: {error!r}\n{block.code}")


def _run_in_own_process(block: Block):
    env = dict(os.environ, MPLBACKEND="Agg")
    try:
        done = subprocess.run(
            [sys.executable, "-c", block.code],
            cwd=ROOT,
            env=env,
            capture_output=True,
            text=True,
            timeout=TIMEOUT_S,
        )
    except subprocess.TimeoutExpired:
        pytest.fail(f"{block_id(block)}: did not finish in {TIMEOUT_S} s")
    assert done.returncode == 0, (
        f"{block_id(block)} failed (exit {done.returncode}):\n{block.code}\n"
        f"--- stderr ---\n{done.stderr[-4000:]}"
    )


# --- links
# -------------------------------------------------------------------------------------------

LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
REFERENCE = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s+.*)?$", re.M)
CODE_SPAN = re.compile(r"(`+)(.+?)\1", re.S)
HEADING = re.compile(r"^\s{0,3}(#{1,6})\s+(.*?)\s*#*\s*$")


def prose(page: Path) -> str:
    """The page without its fenced code blocks and code spans (where brackets are code, not
    links)."""
    lines = page.read_text(encoding="utf-8").splitlines()
    inside = {n for b in blocks(page) for n in range(b.line, b.end + 1)}
    kept = "\n".join(ln for n, ln in enumerate(lines, 1) if n not in inside)
    return CODE_SPAN.sub(" ", kept)


def anchors(page: Path) -> set[str]:
    """GitHub's anchors for the page's headings: the rendered text, lower case, without punctuation
    (hyphens and underscores kept), spaces as hyphens; a repeated one gets -1, -2, ..."""
    lines = page.read_text(encoding="utf-8").splitlines()
    inside = {n for b in blocks(page) for n in range(b.line, b.end + 1)}
    seen: dict[str, int] = {}
    out = set()
    for n, ln in enumerate(lines, 1):
        m = HEADING.match(ln)
        if n in inside or not m:
            continue
        text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", m.group(2))  # a link's text
        text = text.replace("`", "")
        slug = re.sub(r"[^\w\- ]", "", text.strip().lower()).replace(" ", "-")
        if slug in seen:
            seen[slug] += 1
            slug = f"{slug}-{seen[slug]}"
        else:
            seen[slug] = 0
        out.add(slug)
    return out


def links(page: Path) -> list[str]:
    text = prose(page)
    return LINK.findall(text) + REFERENCE.findall(text)


RELATIVE = [
    (page, target)
    for page in PAGES
    for target in links(page)
    # http:, https:, mailto: are not checked
    if not re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", target)
]


def test_every_page_is_reachable_from_the_readme():
    """A reader who starts at README.md reaches every docs page by following links (README links the
    four parts' indexes, each index its pages)."""
    seen, todo = {(ROOT / "README.md").resolve()}, [ROOT / "README.md"]
    while todo:
        page = todo.pop()
        for target in links(page):
            path = target.split("#")[0]
            if re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", target) or not path.endswith(".md"):
                continue
            where = (page.parent / path).resolve()
            if where.is_file() and where not in seen:
                seen.add(where)
                todo.append(where)
    missing = [str(p.relative_to(ROOT)) for p in PAGES[1:] if p.resolve() not in seen]
    assert not missing, f"no chain of links from README.md reaches {missing}"


def test_the_readme_links_the_four_parts():
    linked = {t.split("#")[0] for t in links(ROOT / "README.md")}
    for part in ("tutorials", "how-to", "reference", "explanation"):
        assert f"docs/{part}/index.md" in linked, f"README.md does not link docs/{part}/index.md"


def nav_pages(node) -> list[str]:
    """The pages named in mkdocs.yml's nav, however nested."""
    if isinstance(node, str):
        return [node]
    if isinstance(node, dict):
        return [p for value in node.values() for p in nav_pages(value)]
    return [p for item in node for p in nav_pages(item)]


def test_every_page_is_in_the_sites_nav():
    import yaml

    nav = set(nav_pages(yaml.safe_load((ROOT / "mkdocs.yml").read_text())["nav"]))
    pages = {str(p.relative_to(ROOT / "docs")) for p in PAGES[1:]}
    assert pages - nav == set(), f"mkdocs.yml's nav leaves out {sorted(pages - nav)}"
    assert nav - pages == set(), (
        f"mkdocs.yml's nav names pages that do not exist: {sorted(nav - pages)}"
    )


# The pages say what nma does now; what was measured when, and what changed, is git's and the
# results'.
HISTORY = [
    "before the change",
    "used to",
    "previously",
    "earlier run",
    "was measured",
    "were measured",
    "measured on",
    "this session",
    "predate",
    "as before",
    "than before",
    "before it was",
    "became the default",
    "is now the default",
    "at the time",
]
# "before any work" and its kind are fine; a page that keeps saying "before" tells a story
MAX_BEFORE = 6


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_page_narrates_earlier_runs(page: Path):
    text = " ".join(prose(page).lower().split())
    told = [phrase for phrase in HISTORY if re.search(rf"\b{re.escape(phrase)}\b", text)]
    assert not told, f"{page.relative_to(ROOT)} narrates history: {told}"
    if page == ROOT / "docs" / "reference" / "settings.md":
        # generated: the schema's own words for each setting ("iterations before a load step fails")
        return
    count = len(re.findall(r"\bbefore\b", text))
    assert count <= MAX_BEFORE, (
        f"{page.relative_to(ROOT)} says 'before' {count} times (at most {MAX_BEFORE})"
    )


@pytest.mark.parametrize(
    "page,target", RELATIVE, ids=[f"{p.relative_to(ROOT)}->{t}" for p, t in RELATIVE]
)
def test_relative_link_resolves(page: Path, target: str):
    path, _, fragment = target.partition("#")
    where = (page.parent / path).resolve() if path else page
    assert where.exists(), f"{page.relative_to(ROOT)}: {target} -> {where} does not exist"
    if fragment and where.suffix == ".md":
        assert fragment in anchors(where), (
            f"{page.relative_to(ROOT)}: {target}: no heading with anchor "
            f"#{fragment} in {where.relative_to(ROOT)}"
        )


# --- set-up
# --------------------------------------------------------------------------------------------


def test_ci_runs_the_readmes_set_up_and_test_commands():
    """CI (.ci/run) does what the README's quick start tells a new user: `make install` (a new
    virtual environment with the locked versions), then `make test`; and the lock pins every package
    exactly."""
    quick_start = next(b for b in blocks(ROOT / "README.md") if b.lang == "bash").code
    ci = [line.strip() for line in (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()]
    for command in ("make install", "make test"):
        assert command in quick_start, f"README.md's first bash block does not run {command!r}"
        assert command in ci, f".ci/run does not run {command!r}"
    assert "rm -rf .venv" in ci, ".ci/run must build its environment anew, not reuse one"
    pins = [
        line.split(";")[0].strip()
        for line in (ROOT / "requirements.lock").read_text().splitlines()
        if line.strip() and not line.lstrip().startswith("#")
    ]
    assert pins and all(re.fullmatch(r"[A-Za-z0-9._-]+==[\w.+!-]+", p) for p in pins), pins


def test_the_readme_is_a_quick_start():
    """README.md: at most 100 lines, and no prose paragraph over 80 words (tables, lists and code
    blocks aside)."""
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 100
    prose = re.sub(r"```.*?```", "", text, flags=re.S)
    long = [
        p[:60]
        for p in prose.split("\n\n")
        if not p.lstrip().startswith(("|", "-", "#", "!", "<!--")) and len(p.split()) > 80
    ]
    assert not long, long


def test_the_settings_reference_is_the_schemas():
    """docs/reference/settings.md is what experiments/settings_reference.py writes from today's
    schema: every setting of every group, with its type, default, allowed values and meaning."""
    sys.path.insert(0, str(ROOT / "experiments"))
    try:
        import settings_reference
    finally:
        sys.path.remove(str(ROOT / "experiments"))
    page = ROOT / "docs" / "reference" / "settings.md"
    assert settings_reference.PAGE == page
    assert page.read_text() == settings_reference.page(), (
        "docs/reference/settings.md is stale: python experiments/settings_reference.py"
    )
    text = settings_reference.page()
    for key in (
        "material.nu",
        "solver.corrector",
        "optim.lr_scale.radii",
        "trainer.max_failed_steps",
        "scene.groups",
    ):
        assert f"`{key}`" in text


# --- the site
# -----------------------------------------------------------------------------------------

SITE_TIMEOUT_S = 180  # a guard; the build takes seconds


def test_the_site_builds_with_warnings_as_errors(tmp_path):
    """`make docs`: MkDocs with the Material theme and the API reference from docstrings
    (mkdocstrings), --strict, so a broken link, anchor, nav entry or docstring fails here as in
    `make docs`."""
    pytest.importorskip(
        "mkdocs", reason="the docs extra (pip install -e '.[docs]'; make install has it)"
    )
    try:
        done = subprocess.run(
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
            capture_output=True,
            text=True,
            timeout=SITE_TIMEOUT_S,
            env=dict(os.environ, NO_MKDOCS_2_WARNING="1"),
        )
    except subprocess.TimeoutExpired:
        pytest.fail(f"mkdocs build did not finish in {SITE_TIMEOUT_S} s")
    assert done.returncode == 0, done.stderr[-4000:]
    for page in ("index.html", "reference/api/index.html", "reference/settings/index.html"):
        assert (tmp_path / "site" / page).is_file(), page
    api = (tmp_path / "site" / "reference" / "api" / "index.html").read_text()
    for name in ("Simulator", "equilibrium", "Equilibrium", "Status", "Task", "SceneConfig"):
        assert name in api, f"the API reference does not document {name}"


# The library's front door: each module's docstring examples (>>> lines) run, as doctest reads them.
FRONT_DOOR = [
    "nma.simulator",
    "nma.solver.status",
    "nma.tasks.base",
    "nma.schema.scene",
    "nma.schema.compose",
]


def test_the_front_doors_docstring_examples_run(monkeypatch, capsys):
    import doctest
    import importlib

    monkeypatch.chdir(ROOT)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    tried = failed = 0
    for name in FRONT_DOOR:
        result = doctest.testmod(
            importlib.import_module(name),
            optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE,
        )
        tried, failed = tried + result.attempted, failed + result.failed
    assert tried and not failed, capsys.readouterr().out[-4000:]


def test_the_readmes_results_table_is_the_results():
    """README.md's results table is what experiments/results.py writes from results/*/result.json,
    and every reproduction has its result there, stamped with the commit, date, machine, command and
    wall time."""
    sys.path.insert(0, str(ROOT / "experiments"))
    try:
        import results
    finally:
        sys.path.remove(str(ROOT / "experiments"))
    text = (ROOT / "README.md").read_text()
    assert results.readme_with_table(text) == text, (
        "README.md's results table is stale: python experiments/results.py"
    )
    for name, _ in results.ROWS:
        stamp = json.loads((results.RESULTS / name / "result.json").read_text())["stamp"]
        assert {"commit", "date", "machine", "command", "wall_seconds"} <= set(stamp), name
        assert (results.RESULTS / name / "report.md").is_file()
