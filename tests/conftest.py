import os
import shlex
import sys

os.environ.setdefault("WANDB_MODE", "disabled")


def _fast_suite_only() -> bool:
    """Whether this pytest run keeps pyproject's `-m 'not slow'`: no -m of its own on the command
    line or in PYTEST_ADDOPTS (`-m slow`, `-m ""` and the like select slow tests)."""
    argv = shlex.split(os.environ.get("PYTEST_ADDOPTS", "")) + sys.argv[1:]
    marks = [b for a, b in zip(argv, argv[1:]) if a == "-m"]
    marks += [a[2:] for a in argv if a.startswith("-m") and len(a) > 2]
    return all("slow" in m and "slow" not in m.replace("not slow", "") for m in marks)


# The fast suite compiles some thousand distinct programs and runs most a few times, so XLA's
# compile time outweighs its code's speed there: the CPU backend's legacy emitters and no LLVM
# optimisation compile in about half the time and run at most 2x slower, and each program's code
# generated as one LLVM module (not split for parallel compilation) costs a tenth less CPU time
# again.  Results agree with the optimised programs' to round-off (IEEE arithmetic either way), far
# below the fast tests' tolerances.  The slow suite (long runs, canaries pinned from the commands'
# own programs) compiles as the commands do, and so does NMA_TEST_XLA_FLAGS=off.  The worker
# processes (which inherit the controller's choice) and the commands the tests start take the flags
# from the environment.
TEST_XLA_FLAGS = (
    "--xla_cpu_use_fusion_emitters=false --xla_backend_optimization_level=0 "
    "--xla_cpu_parallel_codegen_split_count=1"
)
if (
    os.environ.get("NMA_TEST_XLA_FLAGS", "on") != "off"
    and "PYTEST_XDIST_WORKER" not in os.environ
    and _fast_suite_only()
):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {TEST_XLA_FLAGS}".strip()

from nma.runtime import configure_jax  # noqa: E402

# As every command does, before any array exists: float64, and JAX's persistent compilation cache,
# so that the worker processes and the commands the tests start share what each of them compiled
configure_jax()

import shutil  # noqa: E402
import subprocess  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from flax import serialization  # noqa: E402
from hydra import compose, initialize_config_dir  # noqa: E402

from nma import config  # noqa: E402
from nma.schema import register  # noqa: E402
from nma.simulator import Simulator  # noqa: E402

# The MPI launcher of the environment the tests run in (the mpich wheel puts it beside the
# interpreter), whether or not that environment is activated
MPIEXEC = (
    shutil.which("mpiexec", path=str(Path(sys.executable).parent))
    or shutil.which("mpiexec")
    or "mpiexec"
)

_SIMS = {}


@pytest.fixture(scope="session")
def simulator():
    """Simulators shared across tests (building and compiling once per scene and backend)."""

    def get(
        scene: str, linear: str = "pardiso", solver: dict | None = None, **fidelity
    ) -> Simulator:
        """`solver`: solver settings besides the backend (the solver group's defaults otherwise)."""
        solver = {"linear": linear, **(solver or {})}
        key = (scene, tuple(sorted(solver.items())), tuple(sorted(fidelity.items())))
        if key not in _SIMS:
            _SIMS[key] = Simulator.from_config(config.load("scene", scene), fidelity, solver)
        return _SIMS[key]

    return get


@pytest.fixture(scope="session")
def barrier_simulator():
    """The translation scene at 5 x 2 with the inversion barrier (J_hat 0.05), Newton converged to
    1e-12 (tight enough for central differences of its solution); shared by the barrier and gradient
    tests."""
    from nma.discretise import Resolution, discretise
    from nma.schema import scene_from_config
    from nma.solver.options import NewtonOptions

    disc = discretise(
        scene_from_config(config.load("scene", "translation")),
        Resolution(5, 2, inversion_barrier=0.05),
    )
    return Simulator(disc, "pardiso", NewtonOptions(rtol=1e-12))


def barrier_case():
    """A random design of the translation scene (radii uniform in [0.1, 0.9]) and a mild actuation
    whose equilibrium at 5 x 2 is inverted between Gauss points near the pinned corner (25, 0)
    without the barrier and without Newton's element bound: the eighth draw of this sequence, found
    by a search over random designs."""
    import numpy as np

    rng = np.random.default_rng(0)
    for _ in range(8):
        radii, d = rng.uniform(0.1, 0.9, (24, 16)), rng.uniform(-4.0, 4.0, 2)
    return radii, d


FAST = [
    "trainer.steps=2",
    "trainer.batch_size=2",
    "trainer.eval_every=2",
    "trainer.progress=false",
    "trainer.animation_frames=3",
    "task.eval_grid=2",
    "fidelity=fast",
]


def compose_cfg(*overrides):
    register()  # the schemas in Hydra's ConfigStore, as every command does on import
    with initialize_config_dir(config_dir=str(config.CONF_DIR), version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


def train_in_process(run_dir, *overrides) -> dict:
    """What `python -m nma.run <overrides>` trains into run_dir, in this process (the same composed,
    checked config and `nma.run.train`; no Hydra run directory or .hydra/ record): for tests whose
    subject is the run's artefacts, not its command line.  The final evaluation's record."""
    from omegaconf import OmegaConf

    from nma.run import train
    from nma.train.runs import validate

    cfg = compose_cfg(*overrides)
    Path(run_dir).mkdir(parents=True, exist_ok=True)
    return train(validate(cfg), Path(run_dir), OmegaConf.to_container(cfg, resolve=True))


def nma_run(run_dir, *overrides, mpi=0, timeout=600, one_core=False):
    """`python -m nma.run` into run_dir; under `mpiexec -n mpi` with each rank bound to a core of
    its own, or with one_core on the first core alone (as a SLURM job with --cpus-per-task=1 runs
    it)."""
    cmd = [sys.executable, "-m", "nma.run", f"hydra.run.dir={run_dir}", *overrides]
    if mpi:
        cmd = [MPIEXEC, "-n", str(mpi), "-bind-to", "core", *cmd]
    if one_core:
        cmd = ["taskset", "-c", str(min(os.sched_getaffinity(0))), *cmd]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc


class HeldElsewhere:
    """Run directories whose lock (nma.cli.RUN_LOCK) another process holds, as a run does from its
    checks to its end: `with HeldElsewhere(dir, ...):`; the lock files name 'process 4242 on
    elsewhere'."""

    def __init__(self, *run_dirs):
        self.locks = [Path(d) / ".lock" for d in run_dirs]

    def __enter__(self):
        for lock in self.locks:
            lock.parent.mkdir(parents=True, exist_ok=True)
        code = (
            "import fcntl, sys, time\n"
            "files = [open(p, 'a+') for p in sys.argv[1:]]\n"
            "for f in files:\n"
            "    fcntl.flock(f, fcntl.LOCK_EX); f.write('process 4242 on elsewhere'); f.flush()\n"
            "print('held', flush=True); time.sleep(300)"
        )
        self.proc = subprocess.Popen(
            [sys.executable, "-c", code, *map(str, self.locks)], stdout=subprocess.PIPE, text=True
        )
        assert self.proc.stdout.readline().strip() == "held"
        return self

    def __exit__(self, *exc):
        self.proc.kill()
        self.proc.wait()


def final_params(run_dir):
    ckpts = sorted((Path(run_dir) / "checkpoints").glob("step_*.msgpack"))
    return serialization.msgpack_restore(ckpts[-1].read_bytes())["params"]


def assert_same_params(a, b, rtol):
    flat_a, flat_b = (dict(_flatten(x)) for x in (a, b))
    assert flat_a.keys() == flat_b.keys()
    for k in flat_a:
        np.testing.assert_allclose(flat_a[k], flat_b[k], rtol=rtol, atol=1e-12, err_msg=k)


def _flatten(tree, prefix=""):
    if isinstance(tree, dict):
        for k, v in tree.items():
            yield from _flatten(v, f"{prefix}/{k}")
    else:
        yield prefix, np.asarray(tree)


@pytest.fixture(scope="session")
def translation_run(tmp_path_factory):
    """A two-step translation run (fidelity fast, wandb offline; an evaluation after each step, the
    first on 2 of the 4 evaluation targets; its units stated: mm and N), shared by the training,
    checkpoint, cluster and evaluation tests, and trained once for all of pytest-xdist's worker
    processes (the first to ask trains it under a lock). It runs on one core: that a run finishes
    there (within nma_run's timeout) is checked with it."""
    import fcntl

    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # the workers' base directories share this parent
    run_dir = root / "translation_run"
    with open(root / "translation_run.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (run_dir / "metrics.json").exists():
            shutil.rmtree(run_dir, ignore_errors=True)
            # in physical units: the paper's E = 0.07 read as MPa (a soft silicone's), a 10 mm cell,
            # 10 mm thick
            nma_run(
                run_dir,
                "task=translation",
                "logger=wandb",
                *FAST,
                "trainer.eval_every=1",
                "trainer.eval_subset=2",
                "material.unit=MPa",
                "part.scale=2",
                "part.thickness=10",
                one_core=True,
                timeout=300,
            )
    return run_dir


def copy_run(src, dst):
    import shutil

    shutil.copytree(src, dst)
    return dst
