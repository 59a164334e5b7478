"""Tasks in time (nma.dynamics): the network maps a descriptor to each actuator's waveform, the
scene moves through time, and the goal is over a window of its trajectory.

- `follow_path`: a tracked point follows a circle through its rest position, of radius r and
  starting direction phi (the descriptor), once per waveform period.
- `energy_focus`: an impulse on one side; the share of the kinetic energy in a region over the
  window, maximised by co-designing the pores and the other actuators' waveforms.

Either is posed on a scene in YAML (conf/task/follow_path.yaml, strip_follow.yaml: its kind's
schema, a scheme, its fields), and takes its time stepping from the simulator
(Simulator.dynamics).

A sample's state is its trajectory (Motion: u and v at every step); every state of it is checked for
validity, and the figures show its last state, the trajectory against its target and the energies.
"""

from __future__ import annotations

import logging
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..dynamics.mass import element_kinetic
from ..dynamics.modes import static_suffices
from ..dynamics.settings import lowest_frequency, time_step
from ..dynamics.waveform import Fourier, Pulse
from ..errors import ConfigError
from .base import Task
from .schemas import EnergyFocusTask, FollowPathTask

log = logging.getLogger(__name__)


class Motion(NamedTuple):
    """A trajectory: displacement and velocity at every time step (steps + 1, n_points, 2)."""

    u: jnp.ndarray
    v: jnp.ndarray


class TimedTask(Task):
    """What the tasks in time share: the dynamics they solve with, the waveform, the window."""

    in_time = True

    def __init__(self, cfg):
        self.cfg, self.d_max = cfg, cfg.d_max
        self.window = slice(cfg.window[0], cfg.window[1] + 1)
        self.dynamics = None

    def attach(self, sim, dcfg, density: float) -> None:
        """The run's time stepping, from the simulator (Simulator.dynamics): dt (by default a 20th
        of the lowest natural period at rest, the one modal solve), then the waveform in steps of
        it; say where the actuation is slow enough for the static model."""
        X, mat = sim.reference_points(sim.init_params()), sim.material_params
        omega_1 = lowest_frequency(sim, X, mat, density)
        self.dt, self.density = time_step(dcfg.dt, omega_1), density
        self.fourier = Fourier(
            self.actuators(sim),
            self.cfg.harmonics,
            self.cfg.period_steps * self.dt,
            self.cfg.ramp_steps * self.dt,
            self.d_max,
        )
        self.dynamics = sim.dynamics(dcfg, self.waveform, density, X=X, mat=mat, omega_1=omega_1)
        said = static_suffices(omega_1, self.cfg.period_steps * self.dt / self.cfg.harmonics)
        if said:
            log.warning("%s", said)

    def actuators(self, sim) -> int:
        return sim.n_actuations

    def waveform(self, coeffs, t):
        """Each actuator's displacement at time t from the network's outputs (bounded by d_max)."""
        return self.fourier(coeffs / self.d_max, t)

    def n_outputs(self, sim) -> int:
        return self.actuators(sim) * (2 * self.cfg.harmonics + 1)

    def solve(self, sim, X, d, mat):
        u, v, info = jax.vmap(self.dynamics.function, in_axes=(None, 0, None))(X, d, mat)
        return Motion(u, v), info

    def states(self, m):
        return m.u

    def at_rest(self, X):
        rest = jnp.zeros((self.dynamics.steps + 1,) + X.shape, X.dtype)
        return Motion(rest, rest)

    def shown(self, m):
        return np.asarray(m.u)[:, -1]

    def check_states(self, checker, m, ok):
        """Every state of every trajectory checked; a sample's Validity is its first state that is
        not physical, else its last."""
        from ..geometry.validity import summarise

        u = np.asarray(m.u)
        n, k = u.shape[:2]
        flat = checker.check_batch(u.reshape((n * k,) + u.shape[2:]), np.repeat(ok, k))
        per = [flat[i * k : (i + 1) * k] for i in range(n)]
        first = [None if s[0] is None else next((v for v in s if not v.valid), s[-1]) for s in per]
        return first, summarise(flat)

    @property
    def times(self) -> np.ndarray:
        return self.dynamics.times

    def element_kinetic(self, sim, X, v):
        """Each element's kinetic energy at every state of velocities v (k, n_points, 2):
        (k, elements), differentiable in X and v (nma.dynamics.mass.element_kinetic)."""
        return element_kinetic(sim.equations, X, v, self.density)

    def kinetic(self, sim, X, v, elements=None):
        """Kinetic energy at every state of a trajectory's velocities v (steps + 1, n_points, 2),
        of the elements weighted by `elements` (all where None)."""
        per = self.element_kinetic(sim, X, v)
        return np.asarray(per.sum(-1) if elements is None else per @ elements)

    def figures(self, directory, sim, evaluation) -> list[str]:
        """energy.png (the kinetic energy over time) and motion.gif (the first evaluation sample
        moving)."""
        from ..viz.motion import animation_motion, figure_energy

        X, m = jnp.asarray(evaluation.X), evaluation.motion
        kinetic = [
            self.kinetic(sim, X, m.v[i]) for i in range(len(evaluation.ts)) if evaluation.ok[i]
        ]
        region = self.region_energies(sim, X, m, evaluation.ok)
        figure_energy(directory / "energy.png", self, self.times, kinetic, region, self.cfg.window)
        points, targets = self.traces(sim, X, m.u[0], evaluation.ts[0])
        animation_motion(
            directory / "motion.gif",
            sim,
            self,
            X,
            m.u[0],
            self.times,
            f"{self.name}: {self.describe(evaluation.ts[0])}",
            points,
            targets,
        )
        return ["energy.png", "motion.gif"]

    def region_energies(self, sim, X, m, ok):
        return None

    def traces(self, sim, X, u, t):
        """(the tracked point at every state, its target there: NaN outside the window) for the
        animation."""
        return None, None


class FollowPath(TimedTask):
    metric_name = "mean_path_error"
    metric_unit = "length units (cell = 5)"
    metric_dimension = "length"
    metric_label = "distance of the point from its moving target"

    def __init__(self, cfg: FollowPathTask, start):
        super().__init__(cfg)
        self.name, self.point, self.start = "follow_path", cfg.point, jnp.asarray(start)
        r = np.linspace(*cfg.radius, cfg.eval_radii)
        phi = np.linspace(0.0, 2 * np.pi, cfg.eval_phases, endpoint=False)
        self._eval = jnp.asarray(np.stack(np.meshgrid(r, phi, indexing="ij"), -1).reshape(-1, 2))

    def sample(self, key, n):
        kr, kp = jax.random.split(key)
        r = jax.random.uniform(kr, (n,), minval=self.cfg.radius[0], maxval=self.cfg.radius[1])
        return jnp.stack([r, jax.random.uniform(kp, (n,), maxval=2 * jnp.pi)], -1)

    def net_input(self, t):
        return jnp.stack([t[..., 0], jnp.cos(t[..., 1]), jnp.sin(t[..., 1])], -1)

    def observe(self, sim, geom, X, m, mat):
        return jax.vmap(lambda ui: sim.tracked(X, ui)[self.point])(m.u[self.window])

    def targets(self, t):
        """The circle through the rest position: start + r (e(omega t + phi) - e(phi)) at the
        window's times."""
        omega = 2 * jnp.pi / (self.cfg.period_steps * self.dt)
        angle = omega * jnp.asarray(self.times[self.window]) + t[1]
        return self.start + t[0] * jnp.stack(
            [jnp.cos(angle) - jnp.cos(t[1]), jnp.sin(angle) - jnp.sin(t[1])], -1
        )

    def loss(self, out, t):
        return jnp.mean(jnp.linalg.norm(out - self.targets(t), axis=-1))

    def metric(self, out, t):
        return jnp.mean(jnp.linalg.norm(out - self.targets(t), axis=-1))

    def eval_set(self):
        return self._eval

    def describe(self, t):
        return "r {:.2f}, phi {:.0f} deg".format(float(t[0]), float(np.degrees(t[1])))

    def coordinates(self, ts):
        ts = np.asarray(ts)
        return np.stack([ts[:, 0] * np.cos(ts[:, 1]), ts[:, 0] * np.sin(ts[:, 1])], -1), [
            "r cos(phi) [length units]",
            "r sin(phi) [length units]",
        ]

    def figures(self, directory, sim, evaluation) -> list[str]:
        from ..viz.motion import figure_paths

        figure_paths(directory / "trajectory.png", self, evaluation)
        return ["trajectory.png", *super().figures(directory, sim, evaluation)]

    def traces(self, sim, X, u, t):
        points = np.asarray(jax.vmap(lambda ui: sim.tracked(X, ui)[self.point])(jnp.asarray(u)))
        targets = np.full_like(points, np.nan)
        targets[self.window] = np.asarray(self.targets(t))
        return points, targets

    def frozen_floor(self):
        """The initial design and its two horizontal actuators are mirror-symmetric about the
        pointer's row: with the geometry frozen the pointer moves sideways only, so at best the
        target's vertical offset stays, averaged over the window."""
        if self.dynamics is None:
            return None
        err = [
            np.mean(np.abs(np.asarray(self.targets(t))[:, 1] - float(self.start[1])))
            for t in self._eval
        ]
        return float(np.mean(err)), (
            "the pointer of the mirror-symmetric initial design moves sideways only"
        )


def follow_path(cfg: FollowPathTask, sim) -> FollowPath:
    X = sim.reference_points(sim.init_params())
    return FollowPath(cfg, sim.disc.tracked_points(X)[cfg.point])


class EnergyFocus(TimedTask):
    metric_name = "region_energy_share"
    metric_unit = "% of the kinetic energy"
    metric_label = "share of the kinetic energy in the region"
    higher_is_better = True

    def __init__(self, cfg: EnergyFocusTask, elements: np.ndarray):
        super().__init__(cfg)
        self.name, self.elements = "energy_focus", jnp.asarray(elements)

    def attach(self, sim, dcfg, density):
        self.n_act = sim.n_actuations
        self.pulse = None
        super().attach(sim, dcfg, density)
        self.pulse = Pulse(self.cfg.pulse_amplitude, self.cfg.pulse_steps * self.dt)

    def actuators(self, sim) -> int:
        return sim.n_actuations - 1  # the network's: every actuator but the pulse's

    def waveform(self, coeffs, t):
        driven = self.fourier(coeffs / self.d_max, t)
        pulse = self.pulse(t) if self.pulse is not None else 0.0 * t
        k = self.cfg.pulse_actuation
        return jnp.concatenate([driven[:k], jnp.atleast_1d(pulse), driven[k:]])

    def sample(self, key, n):
        return jnp.zeros((n, 1))

    def net_input(self, t):
        """A constant input, one: one task, one waveform (a zero input would give the output
        layer, which has no bias, nothing to scale)."""
        return jnp.ones_like(t)

    def observe(self, sim, geom, X, m, mat):
        """The region's share of the kinetic energy at each step of the window."""
        per = self.element_kinetic(sim, X, m.v[self.window])
        return (per @ self.elements) / jnp.maximum(per.sum(-1), 1e-300)

    def targets(self, t):
        return jnp.ones(self.cfg.window[1] - self.cfg.window[0] + 1)

    def shown_target(self, out, t):
        return None  # a share over time, not points to draw

    def loss(self, out, t):
        return -jnp.mean(out)

    def metric(self, out, t):
        return 100.0 * jnp.mean(out)

    def eval_set(self):
        return jnp.zeros((1, 1))

    def describe(self, t):
        return "impulse, then the region's share"

    def region_energies(self, sim, X, m, ok):
        return [self.kinetic(sim, X, m.v[i], self.elements) for i in range(len(ok)) if ok[i]]

    def rest_metric(self, sim, mat):
        return 0.0  # nothing moves: no kinetic energy anywhere


def energy_focus(cfg: EnergyFocusTask, sim) -> EnergyFocus:
    X = np.asarray(sim.reference_points(sim.init_params()))
    centres = X[np.asarray(sim.disc.mesh.elem_points).reshape(-1, 9)].mean(axis=1)
    x0, y0, x1, y1 = cfg.region
    inside = (
        (centres[:, 0] >= x0)
        & (centres[:, 0] <= x1)
        & (centres[:, 1] >= y0)
        & (centres[:, 1] <= y1)
    )
    if not inside.any():  # a share of nothing: no design can raise it
        lo, hi = centres.min(axis=0), centres.max(axis=0)
        raise ConfigError(
            f"task.region={list(cfg.region)} holds no element of scene "
            f"{sim.disc.spec.name} (an element is in it where its centre is; the "
            f"centres span x {lo[0]:.3g} to {hi[0]:.3g}, y {lo[1]:.3g} to "
            f"{hi[1]:.3g} at rest)"
        )
    return EnergyFocus(cfg, inside.astype(float))
