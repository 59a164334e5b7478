"""The simulator facade: a scene, built once, with its solver; what tasks and commands call.

```python
sim = Simulator.from_config(scene_cfg, fidelity=..., solver=...)
X = sim.reference_points(params)        # differentiable design map
u, info = sim.equilibrium(X, d, mat)    # an Equilibrium, differentiable (jit/grad friendly)
eq = sim.solve(params, d, mat)          # eager, on the host: raises SolverError unless converged
eq = sim.solve(params, d, mat, throw=False)  # or returns it failed: sim.failure(eq, d, mat)
```
"""

from __future__ import annotations

import contextlib
from functools import partial
from typing import Any, Mapping

import jax
import jax.numpy as jnp
import numpy as np

from . import checks
from .errors import ConfigError, SolverError
from .discretise import Discretisation, discretise
from .mechanics.energy import quadrature, strain_energy
from .resolve import contact_options, library_settings, material_of, material_params, newton_options
from .runtime import available_cores
from .schema import scene_from_config
from .solver.equations import Equations, tangents_at
from .solver.implicit import make_equilibrium
from .solver.linear import make_backend
from .solver.status import Equilibrium
from .solver.options import WARM_START_NEEDS_HOST, NewtonOptions


class Simulator:
    """A scene discretised once, with its linear solver and Newton's options: what every task and
    command solves with.

    Build one with `from_config` (plain mappings or preset names, as a script would) or
    `from_settings` (a command's checked settings); the constructor takes the discretisation and
    Newton's options as Python objects.

    Args:
        disc: The discretisation (`nma.discretise.discretise`): patches, merged control points,
            actuated groups, supports and quadrature.
        linear: A linear backend registered in `nma.solver.linear`: `auto` (PARDISO where Intel MKL
            installs, else SuperLU), `pardiso`, `superlu` or `dense` (traced: runs under
            `jit`/`vmap`).
        options: Newton's options (`nma.solver.options.NewtonOptions`).
        workers: Threads solving a batch's samples at once (host backends); 0: one per core.

    Raises:
        ConfigError: Options the backend cannot serve (saddle escape without inertia, warm starts
            on a traced backend).

    Examples:
        >>> import jax.numpy as jnp
        >>> from nma.mechanics.material import material
        >>> sim = Simulator.from_config("translation", fidelity="fast")
        >>> sim.n_actuations
        2
        >>> X = sim.reference_points(sim.init_params())
        >>> u, info = sim.equilibrium(X, jnp.array([1.0, -0.5]), material(0.07, 0.3))
        >>> int(info.status)  # Status.CONVERGED
        1
        >>> u.shape == X.shape
        True
    """

    def __init__(
        self,
        disc: Discretisation,
        linear: str = "auto",
        options: NewtonOptions = NewtonOptions(),
        workers: int = 0,
    ):
        self.disc = disc
        self.options = options
        # the material's parameter array, where a config named it (from_config)
        self.material_params = None
        self.backend = make_backend(linear, disc)
        if options.escape_saddles and not getattr(self.backend, "reports_inertia", False):
            raise ConfigError(
                f"solver.escape_saddles needs a linear solver that reports the inertia of its "
                f"factorisation (pardiso); solver.linear={self.backend.name} does not"
            )
        if options.warm_start and self.backend.traceable:
            raise ConfigError(f"solver.warm_start {WARM_START_NEEDS_HOST}")
        self.equations = Equations(disc)
        # threads solving a batch's samples at once (a traced backend batches under vmap instead)
        self.workers = 1 if self.backend.traceable else workers or available_cores()
        # warm_starts: the equilibria kept as starting points (solver.warm_start), None where none
        # are
        self._equilibrium, self.warm_starts = make_equilibrium(
            self.equations, self.backend, options, self.workers
        )
        # the Hessian's element blocks at a state
        self._tangents = jax.jit(partial(tangents_at, self.equations))
        self._solve = jax.jit(
            lambda params, d, mat: self.equilibrium(self.reference_points(params), d, mat)
        )
        self._energy = jax.jit(
            lambda X, u, mat: strain_energy(disc.solid, quadrature(disc.solid, X), u, mat)
        )

    @classmethod
    def from_settings(cls, s, workers: int | None = None) -> "Simulator":
        """A simulator from a command's checked settings: every command builds its simulator here.

        Args:
            s: Any object with `scene`, `fidelity`, `contact`, `material` and `solver` as the
                commands check and resolve them (`TrainConfig`, `SimulateConfig`): `fidelity=auto`
                and the auto choices already made.
            workers: Threads in place of `solver.workers`; None: `solver.workers`.

        Returns:
            The simulator of those settings (ConfigError for a periodic scene).
        """
        if getattr(s.scene, "periodic", False):
            raise ConfigError(
                f"scene {s.scene.name} is periodic: the Simulator solves finite scenes held by "
                "their supports (nma.periodic.periodic_cell builds a periodic one)"
            )
        disc = discretise(
            scene_from_config(s.scene),
            s.fidelity,
            contact_options(s.contact),
            material_of(s.material),
            s.scene.body_force(s.material.density),
            s.material.density,
        )
        sim = cls(
            disc,
            s.solver.linear,
            newton_options(s.solver),
            s.solver.workers if workers is None else workers,
        )
        sim.material_params = material_params(s.material)
        return sim

    @classmethod
    def from_config(
        cls,
        scene: Mapping[str, Any],
        fidelity: Mapping[str, Any] | None = None,
        solver: Mapping[str, Any] | None = None,
        contact: Mapping[str, Any] | None = None,
        formulation: str = "auto",
        material: Mapping[str, Any] | str | None = None,
    ) -> "Simulator":
        """A simulator from plain mappings, without Hydra: each checked as the commands check it,
        and what is left to auto decided for the scene and the material (`nma.resolve`).

        Each settings argument is a mapping of that config group's fields, a preset's name
        (`conf/<group>/<name>.yaml`), a checked schema instance, or None for the defaults.

        Args:
            scene: The scene (`nma.schema.scene.SceneConfig`'s fields, or `"translation"` etc.).
            fidelity: The discretisation; None: the scene's own (`fidelity=scene`).
            solver: Newton's and the linear solver's settings; None: the defaults.
            contact: Contact between pore walls; None: none. `{"enabled": None}` (contact=auto)
                follows the scene.
            formulation: `displacement`, `mixed` (locking-free as nu -> 0.5) or `auto`: by the
                material's nu.
            material: The material (`nma.schema.physics.MaterialConfig`'s fields, or a preset's
                name, `"yeoh"` etc.); None: the paper's Neo-Hookean.  Its own formulation, where not
                auto, replaces `formulation`; its volume term (`volumetric`) left auto is the
                scene's (the paper's scenes and strip: bulk), else lame.
                `sim.material_params` is its parameter array.

        Returns:
            The simulator.

        Raises:
            ConfigError: A setting out of its range, or a scene that cannot be a physical set-up,
                with the field named.

        Examples:
            >>> from nma import config
            >>> scene = {**config.load("scene", "translation"), "radii_init": 0.3}
            >>> sim = Simulator.from_config(scene, fidelity={"quad_points": 3}, solver="superlu")
            >>> sim.init_params()["radii"].shape
            (24, 16)
        """
        return cls.from_settings(
            library_settings(scene, fidelity, solver, contact, formulation, material)
        )

    @property
    def n_actuations(self) -> int:
        """The number of actuations a solve takes: one per actuation index of the scene's groups."""
        return self.disc.boundary.n_actuations

    def init_params(self):
        """The initial design: a dict of arrays holding what the scene models (`radii`
        (n_porous_cells, 16), and `corners`, `pore_radii`, `colours` where the scene has them), at
        the scene's initial values."""
        return self.disc.init_params()

    def reference_points(self, params) -> jnp.ndarray:
        """The design map: the reference control points of a design, differentiable in `params`.

        Args:
            params: The design, as `init_params()` gives it (checked by `check_params`).

        Returns:
            The merged reference control points X, shape (n_points, 2).
        """
        return self.disc.reference_points(self.check_params(params))

    def check_params(self, params) -> dict:
        """The design parameters as init_params() has them, checked, naming the entry: the same keys
        and shapes, real numbers, and a concrete value finite and inside the design's box
        (design.bounds(), where training projects them: radii in scene.radii_bounds, corner moves in
        scene.corner_box)."""
        return checks.design(
            params, self.init_params(), self.disc.design.bounds(), self.disc.spec.name
        )

    def check_actuation(self, d) -> jnp.ndarray:
        """Actuations as a float64 array of n_actuations finite entries; ConfigError otherwise."""
        return checks.actuation(d, self.n_actuations, self.disc.spec.name)

    def equilibrium(self, X, d, mat) -> Equilibrium:
        """The equilibrium under actuation d (n_actuations,) of the design with reference points X
        (n_points, 2) and material mat: differentiable in all three; under jit a failed solve says
        so in its info.status.  Shapes and dtypes are checked here, naming the argument (under vmap:
        one sample's), and a concrete argument's finiteness and range (under jit a non-finite input
        ends the solve at once, info.status NONFINITE_INPUT); other real precisions are taken as
        float64. Its derivative is implicit: the backward pass solves one adjoint system with the
        tangent at the solution.  It works under `jax.jit`, `jax.grad` and `jax.vmap` (see
        `equilibrium_batch`).

        Args:
            X: Reference control points (n_points, 2), from `reference_points`.
            d: Actuations (n_actuations,): each actuated group moves by d[actuation] * direction.
            mat: The material's parameters: Neo-Hookean's [E, nu]
                (`nma.mechanics.material.material(E, nu)`), another law's its parameters then nu
                (`nma.resolve.material_params`, `sim.material_params`).

        Returns:
            An `Equilibrium` (`u, info = ...`): the displacement of every control point (n_points,
            2) and Newton's statistics; `info.status` is a `Status` (1: converged).  A failed
            solve's `u` is its last converged state, at load factor `info.load`.

        Raises:
            ValueError: A concrete argument of the wrong shape, not finite, or a material out of
                range.
            TypeError: An argument that is not an array of real numbers.
        """
        return self._equilibrium(
            checks.solve_input("X", X, (self.disc.mesh.n_points, 2)),
            checks.solve_input("d", d, (self.n_actuations,)),
            checks.material_input(mat, self.disc.material),
        )

    def equilibrium_batch(self, X, ds, mat):
        """Solves for a batch of actuations (n, n_act) on one geometry. Host backends hand the batch
        to their thread pool (each sample's Newton stops when it converges); a pure-JAX backend runs
        the batch in lockstep (parallel on a GPU)."""
        if jnp.ndim(ds) != 2 or jnp.shape(ds)[1] != self.n_actuations:
            raise ValueError(
                f"equilibrium_batch: ds must have shape (n, {self.n_actuations}), a row of "
                f"actuations per sample, got {jnp.shape(ds)}"
            )
        return jax.vmap(lambda d: self.equilibrium(X, d, mat))(ds)

    # -- the solver's state across solves (warm starts): what a trainer asks of it
    # -------------------------
    def cold_solves(self):
        """A context in which every solve starts from rest (warm starts paused; nothing else without
        them)."""
        return (
            self.warm_starts.paused() if self.warm_starts is not None else contextlib.nullcontext()
        )

    def warm_starts_stopped(self) -> str:
        """Why warm starts stopped for good (their audits found several equilibria), or ""."""
        return self.warm_starts.stopped if self.warm_starts is not None else ""

    def solver_record(self) -> dict | None:
        """How the solves since the simulator was built started, and whether warm starts held
        (metrics)."""
        warm = self.warm_starts
        return None if warm is None else {**warm.stats, "other_equilibria": warm.other_equilibria}

    def checkpoint_state(self) -> tuple[int, int] | None:
        """What a checkpoint keeps of the solver, the warm starts' audit tallies, and nothing kept
        after: a run resumed there solves as one not interrupted.  None without warm starts."""
        if self.warm_starts is None:
            return None
        tallies = self.warm_starts.verdict
        self.warm_starts.clear()
        return tallies

    def restore_checkpoint_state(self, tallies) -> None:
        """Go on from a checkpoint's checkpoint_state()."""
        if self.warm_starts is not None:
            self.warm_starts.restore(*tallies)

    def solve(self, params, d, mat, throw: bool = True) -> Equilibrium:
        """Eager forward solve from rest, its result on the host. Unless it converged: raises
        SolverError (with how far it got), or with throw=False returns it as it ended
        (`eq.converged`, `self.failure`).

        Args:
            params: The design, as `init_params()` gives it.
            d: Actuations (n_actuations,).
            mat: The material [E, nu].
            throw: Raise for a failed solve (True) or return it (False).

        Returns:
            The `Equilibrium`, its arrays as numpy arrays.

        Raises:
            SolverError: The solve did not converge (with `throw=True`): the message says the
                status, the load factor reached and the last residual.
            ConfigError: Actuations of the wrong number or not finite.

        Examples:
            >>> from nma.mechanics.material import material
            >>> sim = Simulator.from_config("translation", fidelity="fast")
            >>> eq = sim.solve(sim.init_params(), [0.5, 0.5], material(0.07, 0.3))
            >>> bool(eq.converged), eq.message
            (True, 'converged')
        """
        d, params = self.check_actuation(d), self.check_params(params)
        mat = checks.material_input(mat, self.disc.material)
        with self.cold_solves():
            eq = jax.tree_util.tree_map(
                np.asarray, jax.block_until_ready(self._solve(params, d, mat))
            )
        if throw and not eq.converged:
            raise self.failure(eq, d, mat)
        return eq

    def failure(self, eq: Equilibrium, d, mat) -> SolverError | None:
        """None for a converged solve, else its error: which solve, how far it got and why."""
        return eq.error(
            f"scene {self.disc.spec.name}, actuation {np.asarray(d).tolist()}: ",
            float(self.disc.material.nu(np.asarray(mat))),
        )

    def energy(self, X, u, mat) -> float:
        """The strain energy of the state u: the integral of W over the reference domain."""
        return float(self._energy(X, u, mat))

    def actuation_forces(self, X, u, mat) -> jnp.ndarray:
        """The force each actuation pushes with at the state u (n_actuations,): dW/dd, per unit
        thickness (stress x length; in newtons: nma.units).  Traceable and differentiable."""
        f = jax.grad(
            lambda v: strain_energy(self.disc.solid, quadrature(self.disc.solid, X), v, mat)
        )(u)
        return f.reshape(-1)[self.disc.boundary.dirichlet_dofs] @ jnp.asarray(
            self.disc.boundary.actuation_matrix
        )

    def negative_eigenvalues(self, X, d, mat, u) -> int | None:
        """Unstable modes of an equilibrium u (n_points, 2) of reference points X under actuations d
        and material parameters mat: the number of negative eigenvalues of the Hessian K_ff there
        (0: a stable equilibrium, a local minimum of the energy; > 0: a saddle), or None where the
        linear backend does not report inertia (only PARDISO's LDL^T does)."""
        if not getattr(self.backend, "reports_inertia", False):
            return None
        u_free = jnp.asarray(u).reshape(-1)[self.equations.free]
        return self.backend.negative_eigenvalues(self._tangents(X, jnp.asarray(d), mat, u_free))

    def tracked(self, X, u) -> dict[str, jnp.ndarray]:
        """Deformed positions of the scene's tracked material points: its `tracked` names, each
        mapped to [x, y], of reference control points X and displacements u (n_points, 2);
        differentiable in both."""
        for name, value in (("X", X), ("u", u)):
            if jnp.shape(value) != (self.disc.mesh.n_points, 2):
                raise ValueError(
                    f"tracked: {name} must have shape ({self.disc.mesh.n_points}, 2), got "
                    f"{jnp.shape(value)}"
                )
        return self.disc.tracked_points(X + u)

    def dynamics(self, settings, waveform, density: float = 1.0, **options):
        """The time stepping of this scene under an actuation waveform: an nma.dynamics Dynamics,
        whose `function(X, coeffs, mat)` is the trajectory, differentiable.

        Args:
            settings: A DynamicsConfig (nma.schema.physics; `nma.config.load("dynamics",
                "newmark")`'s fields) or a mapping of its fields: scheme, time step (null: a 20th
                of the lowest natural period at rest), steps, damping, step control, adjoint.
            waveform: f(coeffs, t) -> the actuations at time t (nma.dynamics.waveform.Fourier).
            density: The material's mass per unit area.
            **options: Dynamics.from_settings' X, mat (the design and material whose lowest
                natural frequency sets what the settings leave open), omega_1 (that frequency,
                where the caller has it), workers, v0.
        """
        from .dynamics.trajectory import Dynamics
        from .schema import DynamicsConfig

        if isinstance(settings, Mapping):  # checked as the config's; a scheme where none is named
            settings = DynamicsConfig(**{"scheme": "newmark", **settings})
        return Dynamics.from_settings(self, settings, density, waveform, **options)
