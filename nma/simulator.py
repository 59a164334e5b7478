"""The simulator facade: a scene, built once, with its solver; what tasks and commands call.

    sim = Simulator.from_config(scene_cfg, fidelity=..., solver=...)
    X = sim.reference_points(params)          # differentiable design map
    u, info = sim.equilibrium(X, d, mat)      # differentiable equilibrium (jit/grad friendly)
    sol = sim.solve(params, d, mat)           # eager: raises SolverError unless converged
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from functools import partial
from typing import Any, Mapping

import jax
import jax.numpy as jnp
import numpy as np

from .geometry.discretise import Discretisation, discretise
from .geometry.scene import scene_from_config
from .errors import ConfigError
from .schema import Fidelity, SolverConfig, build
from .mechanics.energy import quadrature, strain_energy
from .solver.implicit import available_cores, make_equilibrium, tangents_at
from .solver.linear import make_backend
from .solver.newton import Equations, NewtonInfo, check_converged
from .solver.options import NewtonOptions


@dataclass
class Solution:
    X: np.ndarray            # (n_points, 2) reference control points
    u: np.ndarray            # (n_points, 2) displacement of every control point
    info: NewtonInfo
    energy: float            # integral of W over the reference domain
    seconds: float

    @property
    def x(self) -> np.ndarray:
        return self.X + self.u


class Simulator:
    def __init__(self, disc: Discretisation, linear: str = "auto", options: NewtonOptions = NewtonOptions(),
                 workers: int = 0):
        self.disc = disc
        self.options = options
        self.backend = make_backend(linear, disc)
        if options.escape_saddles and not getattr(self.backend, "reports_inertia", False):
            raise ConfigError(f"solver.escape_saddles needs a linear solver that reports the inertia of its "
                              f"factorisation (pardiso); solver.linear={self.backend.name} does not")
        self.equations = Equations(disc)
        # threads solving a batch's samples at once (a traced backend batches under vmap instead)
        self.workers = 1 if self.backend.traceable else workers or available_cores()
        self.equilibrium = make_equilibrium(self.equations, self.backend, options, self.workers)
        self._tangents = jax.jit(partial(tangents_at, self.equations))  # the Hessian's element blocks at a state
        self._solve = jax.jit(self._solve_impl)

    @classmethod
    def from_config(cls, scene: Mapping[str, Any], fidelity: Mapping[str, Any] | None = None,
                    solver: Mapping[str, Any] | None = None) -> "Simulator":
        solver = build(SolverConfig, solver)
        return cls(discretise(scene_from_config(scene), build(Fidelity, fidelity)), solver.linear, solver.newton(),
                   solver.workers)

    @property
    def n_actuations(self) -> int:
        return self.disc.n_actuations

    def init_params(self):
        return self.disc.init_params()

    def reference_points(self, params) -> jnp.ndarray:
        return self.disc.reference_points(params)

    def check_actuation(self, d) -> jnp.ndarray:
        d = jnp.atleast_1d(jnp.asarray(d, dtype=jnp.float64))
        if d.shape != (self.n_actuations,):
            raise ConfigError(f"actuation must have {self.n_actuations} entries for scene "
                             f"{self.disc.spec.name}, got shape {tuple(d.shape)}")
        if not np.all(np.isfinite(np.asarray(d))):
            raise ConfigError(f"actuation must be finite, got {np.asarray(d).tolist()}")
        return d

    def equilibrium_batch(self, X, ds, mat):
        """Solves for a batch of actuations (n, n_act) on one geometry. Host backends hand the batch to
        their thread pool (each sample's Newton stops when it converges); a pure-JAX backend runs the
        batch in lockstep (parallel on a GPU)."""
        return jax.vmap(lambda d: self.equilibrium(X, d, mat))(ds)

    def _solve_impl(self, params, d, mat):
        X = self.reference_points(params)
        u, info = self.equilibrium(X, d, mat)
        energy = strain_energy(self.disc, quadrature(self.disc, X), u, mat)
        return X, u, info, energy

    def solve(self, params, d, mat) -> Solution:
        """Eager forward solve; raises SolverError (with how far it got) unless converged."""
        d = self.check_actuation(d)
        t0 = time.perf_counter()
        X, u, info, energy = jax.block_until_ready(self._solve(params, d, mat))
        seconds = time.perf_counter() - t0
        check_converged(info, f"scene {self.disc.spec.name}, actuation {np.asarray(d).tolist()}: ",
                        float(np.asarray(mat)[1]))
        return Solution(np.asarray(X), np.asarray(u), jax.tree_util.tree_map(np.asarray, info),
                        float(energy), seconds)

    def negative_eigenvalues(self, X, d, mat, u) -> int | None:
        """Unstable modes of an equilibrium u: the number of negative eigenvalues of the Hessian K_ff
        there (0: a stable equilibrium, a local minimum of the energy; > 0: a saddle), or None where
        the linear backend does not report inertia (only PARDISO's LDL^T does)."""
        if not getattr(self.backend, "reports_inertia", False):
            return None
        u_free = jnp.asarray(u).reshape(-1)[self.equations.free]
        return self.backend.negative_eigenvalues(self._tangents(X, jnp.asarray(d), mat, u_free))

    def tracked(self, X, u) -> dict[str, jnp.ndarray]:
        """Deformed positions of the scene's tracked material points."""
        return self.disc.tracked_points(X + u)
