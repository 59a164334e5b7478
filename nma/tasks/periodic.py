"""Tasks posed on a periodic material's effective response (nma.periodic): the secant Poisson's
ratio -eps_lateral / eps_axial of a periodic cell compressed under uniaxial nominal stress to
task.strain, through its bifurcation onto the buckled branch, brought to a target.

- `periodic_poisson`: one design (the cell's pore radii, trainer.geometry learned) trained to
  task.target; the network is not used (its outputs are ignored).
- `periodic_poisson_amortised`: a network maps the target to the pore shape, the same D4-symmetric
  pore in every cell (a side's corner and middle radii: 2 numbers, d_max from the initial circles);
  trained over task.train_targets, evaluated on the midpoints between them (held out).

Both start from the scene's initial design (the baseline): circular holes of scene.porosity, or
its radii_init where that is null.  Every state of every path is
checked physical (nma.geometry.validity); a path that could not be completed scores as the
baseline does (never better).  The trainer works on the cell's own simulator (Task.simulator).
"""

from __future__ import annotations

import contextlib

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError
from ..solver.status import NewtonInfo, Status
from .base import Task
from .periodic_schema import PeriodicPoissonTask


class CellSimulator:
    """The cell as the trainer's simulator: its discretisation, design map and checks, its
    initial design the circular holes (the task's baseline).  It solves nothing itself (the task
    follows the load paths: nma.periodic.response), so it keeps no warm starts."""

    n_actuations = 0

    def __init__(self, cell, init):
        self.cell, self.disc, self._init = cell, cell.disc, init
        self.material_params = cell.material_params

    def init_params(self):
        return dict(self._init)

    def reference_points(self, params):
        """The design map, differentiable in params (nma.periodic.cell.PeriodicCell's)."""
        return self.cell.reference_points(params)

    def cold_solves(self):
        return contextlib.nullcontext()

    def warm_starts_stopped(self) -> str:
        return ""

    def solver_record(self):
        return None

    def checkpoint_state(self):
        return None

    def restore_checkpoint_state(self, tallies) -> None:
        pass


class PeriodicPoisson(Task):
    metric_name = "poisson_error"
    metric_unit = "(|Poisson's ratio - target|)"
    metric_label = "|Poisson's ratio - target|"
    solved_outside = True

    def __init__(self, cfg: PeriodicPoissonTask, cell, amortised: bool):
        from ..periodic.designs import circular_holes, porosity
        from ..periodic.load import uniaxial
        from ..periodic.response import Response

        self.name, self.cfg, self.amortised = cfg.name, cfg, amortised
        self.d_max = cfg.d_max
        self.cell = cell
        if cell.porosity is None:
            self.params0 = cell.disc.init_params()
            self.porosity0 = porosity(cell, self.params0)
        else:
            self.params0, self.porosity0 = circular_holes(cell, cell.porosity)
        self.sim = CellSimulator(cell, self.params0)
        self.X0 = self.sim.reference_points(self.params0)
        self.response = Response(self.cell, uniaxial(cfg.axis, cfg.strain), cfg.steps)
        self.frozen_geometry = ("radii",) if amortised else ()
        lo, hi = cfg.target_range
        edges = np.linspace(lo, hi, cfg.train_targets)
        self._train = jnp.asarray(edges[:, None])
        self._eval = jnp.asarray(
            (0.5 * (edges[1:] + edges[:-1]))[:, None] if amortised else [[cfg.target]]
        )
        base = self.response.paths(np.asarray(self.X0)[None])[0]
        self.baseline = {k: np.asarray(v)[0] for k, v in base._asdict().items()}
        if self.baseline["status"] != 1:  # nothing to compare with, nor to score a failure as
            raise ConfigError(
                f"task.strain={cfg.strain}: the initial circular holes' load path could not be "
                "completed to it; choose a smaller compression"
            )
        self.baseline_poisson = float(self.poisson_of(self.baseline["lateral"]))

    def simulator(self, sim):
        return self.sim

    def poisson_of(self, lateral):
        return -(lateral - 1.0) / self.cfg.strain

    # -- the design of each sample --------------------------------------------------------------
    def n_outputs(self, sim) -> int:
        return 2 if self.amortised else 1

    def design_points(self, X, d):
        """(n, n_points, 2) each sample's reference points: the trainer's design (one design), or
        the network's pore (amortised): each side's radii [corner, middle, corner] moved by d
        from the initial circles, the same in every side and cell."""
        n = d.shape[0]
        if not self.amortised:
            return jnp.broadcast_to(X, (n,) + X.shape)
        radii = self.design_radii(d)
        return jax.vmap(lambda r: self.sim.disc.reference_points({"radii": r}))(radii)

    def design_radii(self, d):
        """(n, pores, radii per pore) the network's pores (amortised): the initial circles' radii
        moved by d, clipped to the scene's bounds; a design's parameters at any fidelity."""
        r0 = self.params0["radii"]
        move = jnp.stack([d[:, 0], d[:, 1], d[:, 0]], axis=-1)  # (n, 3): a side
        side = jnp.tile(move, (1, r0.shape[1] // 3))
        lo, hi = self.sim.disc.design.bounds()["radii"]
        return jnp.clip(r0[None] + side[:, None, :], lo, hi)

    # -- a trained design at another fidelity ----------------------------------------------------
    def refined(self, cell, radii) -> dict:
        """The designs `radii` (n, pores, radii per pore: the trained geometry's, or design_radii's
        for the evaluation targets) and the baseline re-solved on `cell`, the run's scene at another
        fidelity: the same design parameters through the same B-spline nets (refined by knot
        insertion: the same pores to round-off), each path followed as the evaluation follows it
        (task.steps output points, every state checked physical).  A failed path scores as the
        baseline at that fidelity does (at the training fidelity where that fails too)."""
        from ..periodic.designs import porosity
        from ..periodic.response import Response

        ts = np.asarray(self._eval)[:, 0]
        if len(radii) != len(ts):
            raise ValueError(f"{len(radii)} designs for {len(ts)} evaluation targets")
        response = Response(cell, self.response.load, self.cfg.steps, mat=self.response.mat)
        designs = [{"radii": jnp.asarray(r)} for r in [self.params0["radii"], *radii]]
        X = np.stack([np.asarray(cell.reference_points(p)) for p in designs])
        out, _ = response.paths(X)
        done = out.status == float(Status.CONVERGED)
        poisson = np.where(done, np.asarray(self.poisson_of(out.lateral)), np.nan)
        base = poisson[0] if done[0] else self.baseline_poisson
        error = np.abs(np.where(done[1:], poisson[1:], base) - ts)
        reached = np.isfinite(out.strain)  # the states each path got to, each one checked
        bad = reached & (out.valid == 0.0)
        crit = [None if np.isnan(c) else float(c) for c in out.critical]
        fid = cell.disc.mesh.fidelity
        return {
            "fidelity": {
                "ctrl_per_patch": int(fid.ctrl_per_patch),
                "quad_points": int(fid.quad_points),
                "dofs": 2 * int(X.shape[1]),
            },
            "value": float(np.mean(error)),
            "per_sample": error.tolist(),
            "reached": [None if not ok else float(p) for ok, p in zip(done[1:], poisson[1:])],
            "failed_solves": int(np.sum(~done[1:])),
            "invalid_states": int(bad[1:].sum()),
            "checked_states": int(reached[1:].sum()),
            "critical_strains": crit[1:],
            "porosity": [porosity(cell, p) for p in designs[1:]],
            "baseline_poisson": float(poisson[0]) if done[0] else None,
            "baseline_critical_strain": crit[0],
            "baseline_error": float(np.mean(np.abs(base - ts))),
            "baseline_invalid_states": int(bad[0].sum()),
        }

    def solve(self, sim, X, d, mat):
        Xs = self.design_points(X, d)
        out = self.response(Xs)
        n = Xs.shape[0]
        status = out.status.astype(jnp.int32)
        zero = jnp.zeros(n)
        info = NewtonInfo(
            status, zero.astype(jnp.int32), zero.astype(jnp.int32), zero.astype(jnp.int32),
            jnp.where(status == 1, 1.0, 0.0), zero, zero, jnp.full((n, 1), jnp.nan),
        )  # fmt: skip
        return {"X": Xs, **out._asdict()}, info

    def at_rest(self, X):
        """A failed path's stand-in: the baseline's (circular holes) response, so that a failure
        scores as the baseline does."""
        b = {k: jnp.asarray(v) for k, v in self.baseline.items()}
        return {"X": self.X0, **b}

    # -- what is read and scored -----------------------------------------------------------------
    def sample(self, key, n):
        if not self.amortised:
            return jnp.full((n, 1), self.cfg.target)
        return self._train[jax.random.randint(key, (n,), 0, len(self._train))]

    def observe(self, sim, geom, X, u, mat):
        return self.poisson_of(u["lateral"])[None]

    def targets(self, t):
        return t

    def loss(self, out, t):
        return jnp.mean((out - t) ** 2)

    def metric(self, out, t):
        return jnp.abs(out - t)[0]

    def eval_set(self):
        return self._eval

    def check_states(self, checker, u, ok):
        """Every state of every path checked against its own reference points; a sample's
        Validity is its first state that is not physical, else its last."""
        from ..geometry.validity import StateChecker, summarise

        X, states = np.asarray(u["X"]), np.asarray(u["u"])
        first, flat = [], []
        for i in range(len(X)):
            if not ok[i]:
                first.append(None)
                continue
            vs = StateChecker(self.sim.disc.mesh, X[i]).check_batch(states[i])
            flat += vs
            first.append(next((v for v in vs if not v.valid), vs[-1]))
        return first, summarise(flat)

    def states(self, u):
        return u["u"]

    def shown(self, u):
        base = np.asarray(self.X0) if self.amortised else np.asarray(u["X"])[:1]
        return np.asarray(u["X"]) - base + np.asarray(u["u"])[:, -1]

    def describe(self, t):
        return f"target Poisson's ratio {float(np.asarray(t)[0]):+.3f}"

    def frozen_floor(self):
        err = np.abs(self.baseline_poisson - np.asarray(self._eval)[:, 0])
        return float(np.mean(err)), "the initial circular holes' Poisson's ratio"

    def rest_metric(self, sim, mat) -> float:
        """The baseline: the initial circular holes' error on the evaluation targets."""
        return self.frozen_floor()[0]


def periodic_poisson(cfg: PeriodicPoissonTask, cell) -> PeriodicPoisson:
    """The task on `cell`, the run's periodic scene's (nma.periodic.front.cell_of)."""
    return PeriodicPoisson(cfg, cell, amortised=False)


def periodic_poisson_amortised(cfg: PeriodicPoissonTask, cell) -> PeriodicPoisson:
    """The amortised task on `cell`."""
    return PeriodicPoisson(cfg, cell, amortised=True)
