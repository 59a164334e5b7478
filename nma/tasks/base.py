"""The small protocol through which the trainer knows a task.

A task samples descriptors t, turns them into network inputs, reads its outputs off an equilibrium
(`observe`), scores them (`loss`, differentiable, per sample) and reports a metric a reader
understands on a fixed evaluation set.  It knows the simulator only through `observe`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


class Task:
    """The task protocol: what the trainer asks of a task.

    A task must give `sample`, `observe`, `targets`, `metric` and `eval_set`; the rest have defaults
    (an L1 `loss`, the mean as `aggregate`, figures' words).  A task is built by a factory
    registered in `nma.registry.TASKS` under its scene's name, with its settings' schema (a
    `nma.tasks.schemas.TaskConfig` subclass); docs/how-to/python-task.md shows one from outside nma.

    Attributes:
        name: The scene the task runs on.
        d_max: The largest actuation: the network's outputs are `d_max * tanh(.)`.
        metric_name: The metric's name in logs and metrics.json (`mean_pointer_error`).
        metric_unit: Its unit in words (`length units (cell = 5)`).
        metric_dimension: `length` or `force` where the metric is one (reported in mm or N where the
            run states its units: nma.units), else None.

    Examples:
        >>> import jax.numpy as jnp
        >>> class Reach(Task):
        ...     name, d_max, metric_name, metric_unit = "strip", 3.0, "error", "length units"
        ...     def targets(self, t):
        ...         return t
        >>> float(Reach().loss(jnp.array([1.0, 2.0]), jnp.array([1.5, 2.0])))
        0.25
        >>> float(Reach().failed_score(0.2, 0.5))  # never better than doing nothing
        0.5
    """

    name: str
    d_max: float
    metric_name: str
    metric_unit: str
    metric_dimension: str | None = None

    def sample(self, key, n: int) -> jnp.ndarray:  # (n, k) descriptors
        """Training descriptors.

        Args:
            key: A JAX random key.
            n: How many.

        Returns:
            (n, k) descriptors t: targets, angles, shapes, images.
        """
        raise NotImplementedError

    def net_input(self, t: jnp.ndarray) -> jnp.ndarray:
        """The network's input for descriptors t (by default t itself)."""
        return t

    def observe(self, sim, geom, X, u, mat) -> jnp.ndarray:
        """What the task reads off an equilibrium: geometry parameters, reference points,
        displacement, and the material (for what depends on it: a reaction force).

        Args:
            sim: The `Simulator` (for `sim.tracked` and the discretisation).
            geom: The design parameters.
            X: Reference control points (n_points, 2).
            u: The equilibrium's displacement (n_points, 2).
            mat: The material [E, nu].

        Returns:
            The observed output of one sample, differentiable in geom, X, u and mat.
        """
        raise NotImplementedError

    def targets(self, t: jnp.ndarray) -> jnp.ndarray:  # what observe should equal, same shape
        """What `observe` should equal for descriptor t, in the same shape."""
        raise NotImplementedError

    def loss(self, out: jnp.ndarray, t: jnp.ndarray) -> jnp.ndarray:
        """L1 distance of the observed points to their targets (the authors' code; the paper's text
        says MSE)."""
        return jnp.mean(jnp.abs(out - self.targets(t)))

    def metric(self, out: jnp.ndarray, t: jnp.ndarray) -> jnp.ndarray:
        """One sample's metric, in `metric_unit`, from its observed output and descriptor."""
        raise NotImplementedError

    def eval_set(self) -> jnp.ndarray:
        """The fixed evaluation descriptors (m, k): the same at every evaluation."""
        raise NotImplementedError

    # -- how the task's states are solved (the static default; a task in time: nma.tasks.timed)
    # ----------
    in_time = False  # True: a sample's state is a trajectory (solve returns one per sample)

    def solve(self, sim, X, d, mat):
        """A batch's states and how their solves went, from the network's outputs d (n, k): by
        default the static equilibria of the actuations d (sim.equilibrium_batch), differentiable in
        X, d and mat."""
        return sim.equilibrium_batch(X, d, mat)

    def simulator(self, sim):
        """The simulator the trainer works on: by default the run's scene's; a task that builds
        its own model (a periodic cell: nma.tasks.periodic) returns that."""
        return sim

    def n_outputs(self, sim) -> int:
        """The network's outputs: by default one actuation per actuated group."""
        return sim.n_actuations

    def check_states(self, checker, u, ok):
        """(each sample's Validity, None where its solve failed; the summary metrics.json records)
        of a batch's states (nma.geometry.validity)."""
        from ..geometry.validity import summarise

        states = checker.check_batch(np.asarray(u), ok)
        return states, summarise(states)

    def at_rest(self, X):
        """What solve gives for one sample where nothing moves."""
        return jnp.zeros_like(X)

    def states(self, u):
        """One sample's states (k, n_points, 2), from what solve gave for it (a static sample:
        one)."""
        return u[None]

    def shown(self, u):
        """The state of each sample that figures draw and fields hold (n, n_points, 2)."""
        return u

    # the metric's direction (an error falls, a count of right answers rises)
    higher_is_better = False
    outline = False  # True: observe() is a closed curve (figures draw it as one)
    # True: the loss compares actuations with actuation_targets(t); nothing is solved
    supervised = False
    frozen_geometry: tuple[str, ...] = ()  # geometry groups this task never learns
    # True: its states come from a solver outside JAX (a periodic load path, nma.periodic), with no
    # derivative in u: trainer.inversion_penalty does not act (each state is checked instead)
    solved_outside = False

    def hidden(self, configured: list[int]) -> list[int]:
        """The encoder's hidden widths for this task."""
        return configured

    def failed_score(self, reached, at_rest):
        """The metric of a sample whose solve failed: the worse of the state it reached (its last
        equilibrium, at part of the load; NaN where there is none) and no actuation at all.  Both
        are states the structure does hold, and taking the worse means a failure never scores better
        than doing nothing, so a design gains nothing by failing the samples it cannot do."""
        worse = np.fmin if self.higher_is_better else np.fmax  # fmin/fmax pass over a NaN
        return worse(np.asarray(reached, dtype=float), np.asarray(at_rest, dtype=float))

    def scored(self, fn, out, ts, ok, at_rest=None):
        """fn(out, t) of every sample, a failed one (ok False) at failed_score against fn(at_rest,
        t): a failed solve is scored, never left out."""
        per = np.asarray(jax.vmap(fn)(out, ts), dtype=float)
        if np.all(ok):
            return per
        return np.where(
            ok, per, self.failed_score(per, jax.vmap(fn, in_axes=(None, 0))(at_rest, ts))
        )

    def sample_metrics(self) -> dict:
        """Further numbers for metrics.json, name -> fn(out, t) of one sample, in the metric's
        direction: each is scored as the metric is (a failed sample at failed_score) and averaged
        over every sample."""
        return {}

    def aggregate(self, per_sample) -> float:
        """The metric of a set of samples from each one's: their mean (a task that counts: their
        sum)."""
        return float(np.mean(per_sample))

    def shown_target(self, out: jnp.ndarray, t: jnp.ndarray) -> jnp.ndarray:
        """The target where a figure draws it next to the observed output."""
        return self.targets(t)

    # -- what figures say in words
    # --------------------------------------------------------------------
    @property
    def metric_label(self) -> str:
        """The metric in words, for axes and titles."""
        return self.metric_name.replace("_", " ")

    def describe(self, t: jnp.ndarray) -> str:
        """One descriptor in words (a panel's title)."""
        return ""

    def coordinates(self, ts: jnp.ndarray):
        """(values (n, k), axis labels) placing descriptors on k <= 2 readable axes, or None when
        they have no such axes (shapes, images): figures then show the metric's distribution
        instead."""
        return None

    def sweep(self, n: int) -> jnp.ndarray:
        """Descriptors along the task's range, in order, for the animation (figures/sweep.gif)."""
        return self.eval_set()[:n]

    sweep_fps = 1.0  # frames per second of the animation: slow for a sequence of separate samples

    def next_step(self, run_dir) -> str | None:
        """The command that continues from a finished run in run_dir (a task in phases: the next
        one)."""
        return None

    def frozen_floor(self) -> tuple[float, str] | None:
        """The best metric the initial design can reach with its geometry frozen, where symmetry
        fixes it, with the reason in words; None where it is not known in closed form."""
        return None

    def rest_metric(self, sim, mat) -> float:
        """The metric of the initial design with no actuation (nothing moves): the floor of doing
        nothing."""
        geom = sim.init_params()
        X = sim.reference_points(geom)
        out = self.observe(sim, geom, X, self.at_rest(X), mat)
        return self.aggregate(jax.vmap(lambda t: self.metric(out, t))(self.eval_set()))
