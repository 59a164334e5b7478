"""The documentation cannot rot: every ```python block of README.md and docs/*.md runs, and every
relative link (and its #anchor) points at something that exists.  Bash blocks are not run."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path
from typing import NamedTuple

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
PYTHON = {"python", "py", "python3"}
TIMEOUT_S = 120  # a guard against a hang; the blocks take seconds

FENCE = re.compile(r"^(\s*)(`{3,}|~{3,})\s*([\w+-]*)")


class Block(NamedTuple):
    page: Path
    line: int        # 1-based line of the opening fence
    end: int         # 1-based line of the closing fence (the last line if unclosed)
    lang: str
    code: str


def blocks(page: Path) -> list[Block]:
    """The fenced code blocks of a page (an unclosed fence runs to the end of the page, as in CommonMark)."""
    lines = page.read_text(encoding="utf-8").splitlines()
    found, i = [], 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        indent, fence, lang = m.group(1), m.group(2), m.group(3).lower()
        j, body = i + 1, []
        while j < len(lines) and not re.match(rf"^\s*{re.escape(fence[0])}{{{len(fence)},}}\s*$", lines[j]):
            body.append(lines[j][len(indent):] if lines[j].startswith(indent) else lines[j].lstrip())
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
    assert len(PAGES) > 1, "docs/*.md: no pages"


def test_there_are_python_blocks_to_run():
    """The docs do show code (the library's example); the test below is not vacuous."""
    assert PYTHON_BLOCKS


@pytest.mark.parametrize("block", PYTHON_BLOCKS, ids=block_id)
def test_python_block_runs(block: Block):
    env = dict(os.environ, MPLBACKEND="Agg")
    try:
        done = subprocess.run([sys.executable, "-c", block.code], cwd=ROOT, env=env, capture_output=True,
                              text=True, timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{block_id(block)}: did not finish in {TIMEOUT_S} s")
    assert done.returncode == 0, (f"{block_id(block)} failed (exit {done.returncode}):\n{block.code}\n"
                                  f"--- stderr ---\n{done.stderr[-4000:]}")


# --- links -------------------------------------------------------------------------------------------

LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
REFERENCE = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s+.*)?$", re.M)
CODE_SPAN = re.compile(r"(`+)(.+?)\1", re.S)
HEADING = re.compile(r"^\s{0,3}(#{1,6})\s+(.*?)\s*#*\s*$")


def prose(page: Path) -> str:
    """The page without its fenced code blocks and code spans (where brackets are code, not links)."""
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


RELATIVE = [(page, target) for page in PAGES for target in links(page)
            if not re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", target)]  # http:, https:, mailto: are not checked


def test_docs_link_to_every_page():
    """README.md's "Where to go next" links every docs page."""
    linked = {(ROOT / t.split("#")[0]).resolve() for p, t in RELATIVE if p.name == "README.md"}
    missing = [str(p.relative_to(ROOT)) for p in PAGES[1:] if p.resolve() not in linked]
    assert not missing, f"README.md does not link {missing}"


@pytest.mark.parametrize("page,target", RELATIVE,
                         ids=[f"{p.relative_to(ROOT)}->{t}" for p, t in RELATIVE])
def test_relative_link_resolves(page: Path, target: str):
    path, _, fragment = target.partition("#")
    where = (page.parent / path).resolve() if path else page
    assert where.exists(), f"{page.relative_to(ROOT)}: {target} -> {where} does not exist"
    if fragment and where.suffix == ".md":
        assert fragment in anchors(where), (f"{page.relative_to(ROOT)}: {target}: no heading with anchor "
                                            f"#{fragment} in {where.relative_to(ROOT)}")


# --- set-up --------------------------------------------------------------------------------------------

def test_ci_runs_the_readmes_set_up_and_test_commands():
    """CI (.ci/run) does what the README's quick start tells a new user: `make install` (a new virtual
    environment with the locked versions), then `make test`; and the lock pins every package exactly."""
    quick_start = next(b for b in blocks(ROOT / "README.md") if b.lang == "bash").code
    ci = [line.strip() for line in (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()]
    for command in ("make install", "make test"):
        assert command in quick_start, f"README.md's first bash block does not run {command!r}"
        assert command in ci, f".ci/run does not run {command!r}"
    assert "rm -rf .venv" in ci, ".ci/run must build its environment anew, not reuse one"
    pins = [line.split(";")[0].strip() for line in (ROOT / "requirements.lock").read_text().splitlines()
            if line.strip() and not line.lstrip().startswith("#")]
    assert pins and all(re.fullmatch(r"[A-Za-z0-9._-]+==[\w.+!-]+", p) for p in pins), pins


def test_the_readme_is_a_quick_start():
    """README.md: at most 100 lines, and no prose paragraph over 80 words (tables, lists and code blocks
    aside)."""
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 100
    prose = re.sub(r"```.*?```", "", text, flags=re.S)
    long = [p[:60] for p in prose.split("\n\n")
            if not p.lstrip().startswith(("|", "-", "#", "!")) and len(p.split()) > 80]
    assert not long, long


def test_the_settings_reference_is_the_schemas():
    """docs/settings.md is what experiments/settings_reference.py writes from today's schema: every
    setting of every group, with its type, default, allowed values and meaning."""
    sys.path.insert(0, str(ROOT / "experiments"))
    try:
        import settings_reference
    finally:
        sys.path.remove(str(ROOT / "experiments"))
    assert (ROOT / "docs" / "settings.md").read_text() == settings_reference.page(), \
        "docs/settings.md is stale: python experiments/settings_reference.py"
    text = settings_reference.page()
    for key in ("material.nu", "solver.corrector", "optim.lr_scale.radii", "trainer.max_failed_steps", "scene.groups"):
        assert f"`{key}`" in text

