"""The tests themselves: every test checks something that could fail, and its name fits a line."""

import ast
import subprocess
import sys
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent
EXPECTING = {"raises", "warns", "fail", "approx"}  # pytest's own ways to expect an outcome


def _checks(node: ast.AST, helpers: dict[str, ast.AST], seen: set[str]) -> bool:
    """Whether `node` asserts, expects an exception or a warning, or calls a helper of its module
    (or a fixture-free function named assert_*/check_*) that does."""
    for sub in ast.walk(node):
        if isinstance(sub, ast.Assert):
            return True
        if isinstance(sub, ast.Call):
            f = sub.func
            name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
            if name.startswith("assert") or name in EXPECTING and _is_pytest(f):
                return True
            if name in helpers and name not in seen:
                seen.add(name)
                if _checks(helpers[name], helpers, seen):
                    return True
    return False


def _is_pytest(f) -> bool:
    return isinstance(f, ast.Attribute) and getattr(f.value, "id", "") == "pytest"


def _test_functions():
    for path in sorted(TESTS.glob("test_*.py")):
        tree = ast.parse(path.read_text())
        helpers = {n.name: n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)}
        conftest = ast.parse((TESTS / "conftest.py").read_text())
        helpers.update({n.name: n for n in conftest.body if isinstance(n, ast.FunctionDef)})
        for node in ast.walk(tree):
            if isinstance(node, ast.FunctionDef) and node.name.startswith("test_"):
                yield path.name, node, helpers


def test_every_test_asserts_or_expects_an_exception():
    silent = [
        f"{file}:{node.lineno} {node.name}"
        for file, node, helpers in _test_functions()
        if not _checks(node, helpers, {node.name})
    ]
    assert not silent, "tests that check nothing:\n" + "\n".join(silent)


def test_no_test_name_is_longer_than_80_characters():
    long = [
        f"{file}:{node.lineno} {node.name} ({len(node.name)})"
        for file, node, _ in _test_functions()
        if len(node.name) > 80
    ]
    assert not long, "test names over 80 characters:\n" + "\n".join(long)


@pytest.mark.parametrize("check", [["format", "--check"], ["check"]])
def test_the_code_is_formatted_to_100_columns_and_lints_clean(check):
    """ruff with pyproject.toml's settings (make format fixes the format, make lint runs both)."""
    done = subprocess.run(
        [sys.executable, "-m", "ruff", *check, "nma", "experiments", "tests"],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
