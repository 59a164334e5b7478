"""Linear-solver backends for the Newton systems (K_ff + shift I) x = b, chosen by name in config.

Host backends (PARDISO, SuperLU) run behind `jax.pure_callback`, so one jitted Newton serves every
backend and batches run sequentially under vmap; the `dense` backend is pure JAX (vmap-parallel on a
GPU).  The adjoint solve reuses the last factorisation as a preconditioner of iterative refinement
against the exact Hessian at the solution, and refactorises only if that does not converge.
"""
from __future__ import annotations

import threading

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse.linalg as spla

from ..geometry.discretise import Discretisation
from ..registry import LINEAR_SOLVERS
from .assembly import element_entries, sparse_pattern

REFINE_RTOL = 1e-13
REFINE_STEPS = 8


class HostBackend:
    """Shared host-side logic: assemble from element tangents, factor, solve, refine."""
    name = "host"
    upper = False

    def __init__(self, disc: Discretisation):
        self.pattern = sparse_pattern(disc, upper=self.upper)
        self._lock = threading.Lock()
        self._factor = None
        self.stats = {"factorisations": 0, "solves": 0, "adjoint_refactorisations": 0}

    # -- to be provided by a concrete backend
    def _factorise(self, A):  # -> object with .solve(b)
        raise NotImplementedError

    def _matvec(self, A, x):
        return A @ x

    # -- host entry points
    def _solve_host(self, kel, rhs, shift):
        with self._lock:
            A = self.pattern.matrix(np.asarray(kel), float(shift))
            self._factor = self._factorise(A)
            self.stats["factorisations"] += 1
            self.stats["solves"] += 1
            return np.asarray(self._factor.solve(np.asarray(rhs, dtype=np.float64)), dtype=np.float64)

    def _adjoint_host(self, kel, rhs):
        with self._lock:
            rhs = np.asarray(rhs, dtype=np.float64)
            A = self.pattern.matrix(np.asarray(kel))
            scale = np.linalg.norm(rhs)
            if scale == 0.0:  # e.g. a sample masked out of the loss
                return np.zeros_like(rhs)
            if self._factor is not None:
                x = self._factor.solve(rhs)
                for _ in range(REFINE_STEPS):
                    r = rhs - self._matvec(A, x)
                    if np.linalg.norm(r) <= REFINE_RTOL * scale:
                        return x
                    x = x + self._factor.solve(r)
                if np.linalg.norm(rhs - self._matvec(A, x)) <= REFINE_RTOL * scale:
                    return x
            self._factor = self._factorise(A)
            self.stats["adjoint_refactorisations"] += 1
            return np.asarray(self._factor.solve(rhs), dtype=np.float64)

    # -- traced entry points
    def solve(self, kel, rhs, shift):
        out = jax.ShapeDtypeStruct(rhs.shape, rhs.dtype)
        return jax.pure_callback(self._solve_host, out, kel, rhs, shift, vmap_method="sequential")

    def adjoint_solve(self, kel, rhs):
        out = jax.ShapeDtypeStruct(rhs.shape, rhs.dtype)
        return jax.pure_callback(self._adjoint_host, out, kel, rhs, vmap_method="sequential")


class _PardisoFactor:
    def __init__(self, solver, A):
        self.solver, self.A = solver, A

    def solve(self, b):
        self.solver.set_phase(33)
        return self.solver._call_pardiso(self.A, np.asfortranarray(b)).reshape(b.shape)


@LINEAR_SOLVERS.register("pardiso")
class PardisoBackend(HostBackend):
    """Intel MKL PARDISO, symmetric indefinite (mtype -2): symbolic analysis once per pattern,
    numerical refactorisation (phase 22) per Newton iteration."""
    name = "pardiso"
    upper = True

    def __init__(self, disc: Discretisation):
        super().__init__(disc)
        try:
            import pypardiso
        except ImportError as exc:  # pragma: no cover - depends on the platform's MKL wheels
            raise RuntimeError("solver.linear=pardiso needs pypardiso (MKL); use superlu instead") from exc
        self.solver = pypardiso.PyPardisoSolver(mtype=-2)
        self._analysed = False

    def _factorise(self, A):
        A.sort_indices()
        b = np.zeros((A.shape[0], 1))
        if not self._analysed:
            self.solver.set_phase(11)
            self.solver._call_pardiso(A, b)
            self._analysed = True
        self.solver.set_phase(22)
        self.solver._call_pardiso(A, b)
        return _PardisoFactor(self.solver, A)

    def _matvec(self, A, x):
        return A @ x + A.T @ x - A.diagonal() * x


@LINEAR_SOLVERS.register("superlu")
class SuperLUBackend(HostBackend):
    """scipy's SuperLU: portable, no extra dependency."""
    name = "superlu"

    def _factorise(self, A):
        return spla.splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A")


@LINEAR_SOLVERS.register("dense")
class DenseBackend:
    """Pure JAX: dense assembly and LU solve. Traceable, vmap-parallel; meant for GPUs."""
    name = "dense"
    parallel_batches = True  # batches run in lockstep under vmap

    def __init__(self, disc: Discretisation):
        rows, cols = element_entries(disc)
        keep = np.flatnonzero((rows >= 0) & (cols >= 0))
        self.n = disc.n_dofs
        self.keep, self.rows, self.cols = keep, rows[keep], cols[keep]
        self.stats = {}  # counts happen inside traced code; nothing to report

    def _matrix(self, kel, shift):
        K = jnp.zeros((self.n, self.n), kel.dtype).at[self.rows, self.cols].add(kel.reshape(-1)[self.keep])
        return K + shift * jnp.eye(self.n, dtype=kel.dtype)

    def solve(self, kel, rhs, shift):
        return jnp.linalg.solve(self._matrix(kel, shift), rhs)

    def adjoint_solve(self, kel, rhs):
        return jnp.linalg.solve(self._matrix(kel, 0.0), rhs)


def make_backend(name: str, disc: Discretisation):
    return LINEAR_SOLVERS.get(name)(disc)
