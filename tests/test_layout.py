"""The package's layers (docs/reference/layout.md): no import circle, the config schema read only by
the command layer, and a schema that loads without JAX.  Imports are read from the source (ast), the
lazy ones inside functions included; those under `if TYPE_CHECKING:` are annotations for the reader
and do not count."""

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# the modules that turn checked settings into objects: the commands, their helpers (nma.cli's
# modules among them), the one resolver of `auto`, and the library's front doors
# (Simulator.from_config and nma.periodic's periodic_cell take the same settings as the commands;
# nma.periodic.command is nma.simulate's periodic branch)
COMMAND_LAYER = {
    "nma.cli",
    "nma.cli.compose",
    "nma.cli.exits",
    "nma.cli.output",
    "nma.cli.preflight",
    "nma.cli.rundirs",
    "nma.config",
    "nma.run",
    "nma.simulate",
    "nma.evaluate",
    "nma.export",
    "nma.fit",
    "nma.sweep",
    "nma.fidelity",
    "nma.resolve",
    "nma.simulator",
    "nma.train.runs",
    "nma.periodic",
    "nma.periodic.front",
    "nma.periodic.command",
}


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: Path) -> set[str]:
    """The nma modules `path` imports anywhere in its body (a name imported from a package counts as
    the submodule of that name where there is one)."""
    me = module_name(path)
    package = me if path.name == "__init__.py" else me.rpartition(".")[0]
    found: set[str] = set()

    def is_module(name: str) -> bool:
        p = ROOT.joinpath(*name.split("."))
        return p.with_suffix(".py").is_file() or (p / "__init__.py").is_file()

    def visit(nodes):
        for node in nodes:
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
                continue
            if isinstance(node, ast.Import):
                found.update(a.name for a in node.names if a.name.split(".")[0] == "nma")
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - node.level + 1]
                    module = ".".join(base + ([node.module] if node.module else []))
                else:
                    module = node.module or ""
                if module.split(".")[0] == "nma":
                    found.update(
                        f"{module}.{a.name}" if is_module(f"{module}.{a.name}") else module
                        for a in node.names
                    )
            for child in ast.iter_child_nodes(node):
                visit([child])

    visit(ast.parse(path.read_text()).body)
    return found


GRAPH = {module_name(p): imports(p) for p in (ROOT / "nma").rglob("*.py")}


def test_no_module_imports_one_that_imports_it_back():
    cycles, state, stack = [], {}, []

    def walk(u):
        state[u] = "open"
        stack.append(u)
        for v in sorted(GRAPH.get(u, ())):
            if state.get(v) == "open":
                cycles.append(" -> ".join(stack[stack.index(v) :] + [v]))
            elif v not in state:
                walk(v)
        stack.pop()
        state[u] = "done"

    for module in sorted(GRAPH):
        if module not in state:
            walk(module)
    assert not cycles, cycles


def test_the_schema_is_read_by_the_command_layer_only():
    schema = lambda m: m == "nma.schema" or m.startswith("nma.schema.")
    readers = {m for m, deps in GRAPH.items() if not schema(m) and any(map(schema, deps))}
    assert readers, (
        "the layer test sees no reader of the schema at all: its import parsing is broken"
    )
    assert readers <= COMMAND_LAYER, sorted(readers - COMMAND_LAYER)
    upward = {
        m: sorted(d for d in deps if d in COMMAND_LAYER)
        for m, deps in GRAPH.items()
        if m not in COMMAND_LAYER and (schema(m) or m not in readers)
    }
    # nothing below imports a command
    assert not any(upward.values()), {m: d for m, d in upward.items() if d}


def test_every_cli_module_is_of_the_command_layer():
    cli = {m for m in GRAPH if m == "nma.cli" or m.startswith("nma.cli.")}
    assert len(cli) > 1 and cli <= COMMAND_LAYER, sorted(cli - COMMAND_LAYER)


def test_the_geometry_imports_nothing_of_the_model_built_on_it():
    """The geometry (splines, scenes, meshes) is the bottom of the model: the mechanics integrate
    over its meshes, and nma.discretise, above both, joins them into a scene's model."""
    above = ("nma.mechanics", "nma.solver", "nma.dynamics", "nma.discretise")
    inside = tuple(a + "." for a in above)
    upward = {
        m: sorted(d for d in deps if d in above or d.startswith(inside))
        for m, deps in GRAPH.items()
        if m.startswith("nma.geometry.")
    }
    assert len(upward) > 5, "the layer test sees no geometry module: its import parsing is broken"
    assert not any(upward.values()), {m: d for m, d in upward.items() if d}


def test_the_schema_and_the_task_declarations_load_without_jax():
    code = (
        "import sys, nma.schema, nma.tasks; assert 'jax' not in sys.modules, 'jax'; "
        "print(len(nma.schema.TASK_SCHEMAS))"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert int(proc.stdout) >= 6  # the five paper tasks' schemas (two rotations) and the spec's


def test_every_declared_task_imports_and_a_broken_declaration_names_itself():
    import pytest

    from nma.errors import ConfigError
    from nma.registry import Registry
    from nma.tasks.schemas import TASK_SCHEMAS
    from nma.registry import TASKS

    for name in TASK_SCHEMAS:
        assert callable(TASKS.get(name)), name
    broken = Registry("task.name")
    broken.declare("lost", "nma.tasks.nowhere:factory")
    with pytest.raises(
        ConfigError,
        match="task.name lost is declared as 'nma.tasks.nowhere:factory', which does not "
        "import: ModuleNotFoundError",
    ):
        broken.get("lost")
    with pytest.raises(ValueError, match="'module:attribute'"):
        broken.declare("pathless", "nma.tasks.spec")


def test_no_module_holds_more_than_a_reader_can_keep_in_mind():
    """Every module of nma/ is at most 400 lines: a module over that does several jobs (split
    it)."""
    long = {
        module_name(p): n
        for p in (ROOT / "nma").rglob("*.py")
        if (n := len(p.read_text().splitlines())) > 400
    }
    assert not long, long
