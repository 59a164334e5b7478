"""Linear-solver backends for the Newton systems (K_ff + shift I) x = b, chosen by name in config.

Host backends (SuperLU, PARDISO) factorise scipy matrices assembled from the element tangents; each
sample's Newton solve holds its own `Workspace` (its latest factor), so concurrent samples never
share a factor and the adjoint of a sample reuses that sample's last factor: it preconditions
iterative refinement against the exact Hessian at the solution (a few back-substitutions), and a
refactorisation happens only if that does not converge.  The `dense` backend is pure JAX: its static
Newton loop is traced, and a batch runs in lockstep under vmap (parallel on a GPU); a time step's
Newton is driven from the host as the host backends' are, each factor a dense LU.
"""

from __future__ import annotations

import copy
import functools
import glob
import logging
import os
import sys
import threading
import time
from collections import defaultdict
from contextlib import contextmanager

import jax
import jax.numpy as jnp
import jax.scipy.linalg  # noqa: F401  (jax.scipy.linalg.lu_factor)
import numpy as np
import scipy.sparse.linalg as spla

from ..discretise import Discretisation
from ..registry import LINEAR_SOLVERS
from .assembly import element_entries, sparse_pattern

REFINE_RTOL = 1e-13
REFINE_STEPS = 8


class Stopwatch:
    """Seconds spent per phase of the solver, summed over threads: where a training step's time
    goes."""

    def __init__(self):
        self.seconds: dict[str, float] = defaultdict(float)
        self._lock = threading.Lock()

    @contextmanager
    def time(self, phase: str):
        start = time.perf_counter()
        try:
            yield
        finally:
            with self._lock:
                self.seconds[phase] += time.perf_counter() - start


class Workspace:
    """One sample's linear solver: factorise, then solve with the latest factor."""

    def __init__(self, backend: "HostBackend"):
        self.backend = backend
        self.factor = None

    def factorise(self, kel, shift: float = 0.0) -> None:
        clock = self.backend.clock
        with clock.time("assembly"):
            A = self.backend.pattern.matrix(kel, shift)
        with clock.time("factorisation"):
            self.factor = self.backend.factorise(A, self.factor)
        self.backend.count("factorisations")

    def solve(self, b) -> np.ndarray:
        with self.backend.clock.time("back_substitution"):
            return np.asarray(self.factor.solve(np.asarray(b, dtype=np.float64)), dtype=np.float64)

    def adjoint(self, kel, rhs, refine: bool = True) -> np.ndarray:
        with self.backend.clock.time("adjoint_solve"):
            return self._adjoint(kel, rhs, refine)

    def _adjoint(self, kel, rhs, refine: bool) -> np.ndarray:
        """Solve K x = rhs with K from kel (the Hessian at the solution): refine from this
        workspace's factor (of the last Newton iterate), refactorise only if refinement does not
        converge; with refine=False (a factor known to be too far from K), refactorise at once."""
        rhs = np.asarray(rhs, dtype=np.float64)
        scale = np.linalg.norm(rhs)
        if scale == 0.0:  # e.g. a sample masked out of the loss
            return np.zeros_like(rhs)
        A = self.backend.pattern.matrix(kel)
        if refine and self.factor is not None:
            x = self.solve(rhs)
            for k in range(REFINE_STEPS + 1):
                r = rhs - self.backend.matvec(A, x)
                if np.linalg.norm(r) <= REFINE_RTOL * scale:
                    return x
                if k < REFINE_STEPS:
                    x = x + self.solve(r)
        self.factorise_for_adjoint(kel, A)
        return self.solve(rhs)

    def factorise_for_adjoint(self, kel, A=None) -> None:
        """Factorise K (from kel, or A, its assembly) for the adjoint solves to come (`solve`)."""
        A = self.backend.pattern.matrix(kel) if A is None else A
        self.factor = self.backend.factorise(A, self.factor)
        self.backend.count("adjoint_refactorisations")


class HostBackend:
    """Assembly from element tangents into the scene's fixed CSR pattern; workspaces per sample."""

    name = "host"
    upper = False
    traceable = False

    def __init__(self, disc: Discretisation):
        self.pattern = sparse_pattern(disc, upper=self.upper)
        self._lock = threading.Lock()
        # newton_solves and newton_iterations count every solve, a warm start redone cold too
        self.stats = {
            "factorisations": 0,
            "adjoint_refactorisations": 0,
            "saddles_left": 0,
            "newton_solves": 0,
            "newton_iterations": 0,
        }
        self.clock = Stopwatch()

    def count(self, what: str, n: int = 1) -> None:
        with self._lock:
            self.stats[what] += n

    def workspace(self) -> Workspace:
        return Workspace(self)

    def release(self, ws: Workspace) -> None:
        """A workspace no longer needed (its sample's gradient is done, or none will be asked)."""
        ws.factor = None

    # -- to be provided by a concrete backend
    def factorise(self, A, previous):  # -> object with .solve(b)
        raise NotImplementedError

    reports_inertia = False  # whether a factorisation tells how many eigenvalues are negative

    def inertia(self, ws: Workspace) -> int | None:
        """The number of negative eigenvalues of the matrix ws last factorised, where reported."""
        return None

    def negative_eigenvalues(self, kel) -> int | None:
        """How many eigenvalues of K_ff are negative (where the factorisation reports its inertia):
        0 at a
        stable equilibrium; at a saddle (an unstable equilibrium, e.g. a symmetric path past a
        buckling point) the count of its unstable modes."""
        if not self.reports_inertia:
            return None
        ws = self.workspace()
        try:
            ws.factorise(kel)
            return self.inertia(ws)
        finally:
            self.release(ws)

    def matvec(self, A, x):
        return A @ x


@LINEAR_SOLVERS.register("superlu")
class SuperLUBackend(HostBackend):
    """scipy's SuperLU: portable, no extra dependency, releases the GIL (samples factorise
    concurrently)."""

    name = "superlu"

    def factorise(self, A, previous):
        return spla.splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A")


class _PardisoFactor:
    """A PARDISO handle (symbolic analysis done once) and the matrix of its latest factorisation."""

    def __init__(self, solver):
        self.solver, self.A = solver, None

    def solve(self, b):
        self.solver.set_phase(33)
        return self.solver._call_pardiso(self.A, np.asfortranarray(b)).reshape(b.shape)


def _point_pypardiso_at_mkl() -> None:
    """pypardiso looks for MKL's runtime by a recursive search of the environment (about a second
    per solver); the MKL wheel puts it in the environment's lib directory, so look there first."""
    if "PYPARDISO_MKL_RT" in os.environ:
        return
    for pattern in ("lib/libmkl_rt.so*", "lib/libmkl_rt*.dylib", "Library/bin/mkl_rt*.dll"):
        found = sorted(glob.glob(os.path.join(sys.prefix, pattern)), key=len)
        if found:
            os.environ["PYPARDISO_MKL_RT"] = found[0]
            return


@LINEAR_SOLVERS.register("pardiso")
class PardisoBackend(HostBackend):
    """Intel MKL PARDISO, symmetric indefinite (mtype -2), upper triangle: symbolic analysis once
    per handle, numerical refactorisation (phase 22) per Newton iteration.  A handle holds one
    factor, so each workspace has its own handle, taken from a pool and given back when released."""

    name = "pardiso"
    upper = True
    # iparm[7]: 0 refines a solve (two steps) only where the factorisation perturbed a pivot; MKL's
    # default for this matrix type, 2, refines every solve: two more back-substitutions and two
    # matrix products each time, which changed no Newton or adjoint answer beyond round-off (Newton
    # corrects its own steps, and the adjoint refines against the exact Hessian: Workspace._adjoint)
    refinement_steps = 0

    def __init__(self, disc: Discretisation):
        super().__init__(disc)
        _point_pypardiso_at_mkl()
        try:
            import pypardiso
        # pragma: no cover - a dependency; MKL wheels exist for x86-64 only
        except ImportError as exc:
            raise RuntimeError(
                "solver.linear=pardiso needs pypardiso (Intel MKL): pip install pypardiso, "
                "or use solver.linear=superlu"
            ) from exc
        self._template = pypardiso.PyPardisoSolver(mtype=-2)  # finds and loads MKL (slow): once
        # one thread per factorisation: a batch's samples run in parallel instead, and idle MKL
        # threads spin-wait (stealing the core XLA needs) on systems this small (process-wide; numpy
        # uses no MKL)
        self._template.libmkl.MKL_Set_Num_Threads(1)
        self._idle: list[_PardisoFactor] = []

    def _new_solver(self):
        """A fresh PARDISO handle sharing the template's loaded library."""
        solver = copy.copy(self._template)
        solver.pt, solver.iparm, solver.perm = (
            np.zeros_like(a) for a in (solver.pt, solver.iparm, solver.perm)
        )
        return solver

    def factorise(self, A, previous):
        A.sort_indices()
        b = np.zeros((A.shape[0], 1))
        factor = previous
        if factor is None:
            with self._lock:
                factor = self._idle.pop() if self._idle else None
            if factor is None:
                factor = _PardisoFactor(self._new_solver())
                factor.solver.set_phase(11)
                factor.solver._call_pardiso(A, b)  # fills iparm with MKL's defaults
                factor.solver.iparm[7] = self.refinement_steps
        factor.A = A
        factor.solver.set_phase(22)
        factor.solver._call_pardiso(A, b)
        return factor

    def release(self, ws: Workspace) -> None:
        if ws.factor is not None:
            with self._lock:
                self._idle.append(ws.factor)
        ws.factor = None

    def matvec(self, A, x):
        return A @ x + A.T @ x - A.diagonal() * x

    reports_inertia = True

    def inertia(self, ws: Workspace) -> int:
        """Negative eigenvalues of the last factorised matrix: the inertia of the
        symmetric-indefinite LDL^T factorisation (iparm(23) in MKL's one-based numbering)."""
        return int(ws.factor.solver.iparm[22])


class DenseWorkspace(Workspace):
    """One sample's dense LU (JAX's, on the accelerator where there is one), for Newton driven from
    the host (time steps: nma.dynamics): factorise, then solve with the latest factor."""

    def factorise(self, kel, shift: float = 0.0) -> None:
        with self.backend.clock.time("factorisation"):
            shift = jnp.asarray(shift, kel.elements.dtype)
            self.factor = jax.block_until_ready(self.backend.lu(kel, shift))
        self.backend.count("factorisations")

    def solve(self, b) -> np.ndarray:
        with self.backend.clock.time("back_substitution"):
            x = self.backend.lu_solve(self.factor, jnp.asarray(b, jnp.float64))
            return np.asarray(x, dtype=np.float64)

    def _adjoint(self, kel, rhs, refine: bool) -> np.ndarray:
        """Solve K x = rhs with K from kel: factorised afresh (dense LU is exact to round-off)."""
        rhs = np.asarray(rhs, dtype=np.float64)
        if np.linalg.norm(rhs) == 0.0:
            return np.zeros_like(rhs)
        self.factorise_for_adjoint(kel)
        return self.solve(rhs)

    def factorise_for_adjoint(self, kel, A=None) -> None:
        self.factorise(kel)
        self.backend.count("adjoint_refactorisations")


@LINEAR_SOLVERS.register("dense")
class DenseBackend:
    """Pure JAX: dense assembly and LU solve. Traceable, vmap-parallel; meant for GPUs.  A static
    solve's Newton loop is traced; a time step's (nma.dynamics) is driven from the host as the host
    backends' are, each factor a dense LU (DenseWorkspace).  The natural frequencies take the
    scene's sparse pattern (`pattern`, built when first asked)."""

    name = "dense"
    traceable = True  # the Newton loop is traced; batches run in lockstep under vmap
    reports_inertia = False

    def __init__(self, disc: Discretisation):
        rows, cols = element_entries(disc)
        self.disc = disc
        self.n = disc.boundary.n_dofs
        E = disc.mesh.elem_points.reshape(-1, 9).shape[0] * 18 * 18
        keep = np.flatnonzero((rows[:E] >= 0) & (cols[:E] >= 0))
        self.keep, self.rows, self.cols = keep, rows[keep], cols[keep]
        # each contact block's entries, a Dirichlet dof's row or column past the matrix (dropped)
        self.contact_rows, self.contact_cols = (
            jnp.asarray(np.where(a[E:] >= 0, a[E:], self.n).reshape(-1, 18 * 18))
            for a in (rows, cols)
        )
        # counts of the host-driven solves (time steps); a traced solve counts nothing
        self._lock = threading.Lock()
        self.stats = {
            "factorisations": 0,
            "adjoint_refactorisations": 0,
            "newton_solves": 0,
            "newton_iterations": 0,
        }
        self.clock = Stopwatch()
        self.lu = jax.jit(lambda kel, shift: jax.scipy.linalg.lu_factor(self._matrix(kel, shift)))
        self.lu_solve = jax.jit(lambda factor, b: jax.scipy.linalg.lu_solve(factor, b))

    @functools.cached_property
    def pattern(self):
        """The scene's sparse pattern (nma.solver.assembly): for what needs matrices on the host."""
        return sparse_pattern(self.disc, upper=False)

    # -- Newton driven from the host (HostNewton): time steps
    def count(self, what: str, n: int = 1) -> None:
        with self._lock:
            self.stats[what] = self.stats.get(what, 0) + n

    def workspace(self) -> DenseWorkspace:
        return DenseWorkspace(self)

    def release(self, ws: Workspace) -> None:
        ws.factor = None

    def inertia(self, ws: Workspace) -> None:
        return None

    def negative_eigenvalues(self, kel) -> None:
        return None

    def _matrix(self, kel, shift):
        Ke = kel.elements
        K = (
            jnp.zeros((self.n, self.n), Ke.dtype)
            .at[self.rows, self.cols]
            .add(Ke.reshape(-1)[self.keep])
        )
        if kel.which.shape[-1]:  # empty slots: zero blocks
            at = jnp.maximum(kel.which, 0)
            K = K.at[self.contact_rows[at], self.contact_cols[at]].add(
                kel.contact.reshape(len(at), -1), mode="drop"
            )
        return K + shift * jnp.eye(self.n, dtype=Ke.dtype)

    def solve(self, kel, rhs, shift):
        return jnp.linalg.solve(self._matrix(kel, shift), rhs)

    def adjoint_solve(self, kel, rhs):
        return jnp.linalg.solve(self._matrix(kel, 0.0), rhs)


def pardiso_available() -> bool:
    """Whether PARDISO can run here: pypardiso and Intel MKL install on x86-64 only."""
    import importlib.util

    return importlib.util.find_spec("pypardiso") is not None


@LINEAR_SOLVERS.register("auto")
def auto_backend(disc: Discretisation):
    """PARDISO where Intel MKL installs (x86-64: it factorises the paper scenes' Hessians several
    times faster than SuperLU), SuperLU elsewhere (ARM laptops): the same answers, to round-off."""
    if pardiso_available():
        return PardisoBackend(disc)
    logging.getLogger(__name__).info(
        "solver.linear=auto: no Intel MKL on this platform, using SuperLU"
    )
    return SuperLUBackend(disc)


def make_backend(name: str, disc: Discretisation):
    return LINEAR_SOLVERS.get(name)(disc)
