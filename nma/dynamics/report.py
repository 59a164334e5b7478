"""What `nma.simulate` says about dynamics: the structure's lowest natural frequencies, and with
`dynamics=newmark|generalised_alpha` the actuation applied over time (rising along a smootherstep
over `dynamics.ramp`, then held): every state's validity, the energies, the tracked points over
time against the static equilibrium, and whether the static model would have sufficed.

One modal solve per command: statically about the equilibrium solved; in time at rest (where a run
from rest starts; dynamics.start=static starts at the static equilibrium under the dead load), whose
lowest frequency also sets the time step, the ramp and the damping where the settings leave them
open."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from ..errors import SolverError
from ..mechanics.energy import quadrature, strain_energy
from ..solver.status import Status
from .mass import kinetic_energy
from .modes import ModalFailure, dynamic_amplification, solved, static_suffices
from .waveform import smootherstep

log = logging.getLogger("nma.simulate")
FREQUENCIES = 3  # natural frequencies reported


def frequencies(sim, X, mat, density, d=None, u=None) -> dict:
    """The lowest natural frequencies (rad per unit time) and periods of small vibrations about
    (d, u) (at rest where None), and which state that is; where the modal solve fails (a singular
    tangent: a mechanism, a saddle), null and the reason, logged."""
    about = "rest" if d is None else "equilibrium"
    u_free = (
        None
        if u is None
        else jnp.asarray(np.asarray(u).reshape(-1)[np.asarray(sim.equations.free)])
    )
    try:
        omega = solved(sim, X, mat, density, FREQUENCIES, d, u_free)
    except ModalFailure as err:
        why = f"the natural frequencies about this state could not be computed ({err})"
        log.warning("%s", why)
        return {
            "natural_frequencies": None,
            "natural_periods": None,
            "natural_frequencies_about": about,
            "natural_frequencies_error": why,
        }
    with np.errstate(divide="ignore"):  # a frequency of 0 (no stiffness along a mode): no period
        periods = 2 * np.pi / omega
    out = {
        "natural_frequencies": omega.tolist(),
        "natural_periods": periods.tolist(),
        "natural_frequencies_about": about,
    }
    if np.any(omega == 0):
        out["natural_frequencies_note"] = (
            "a frequency of 0: the tangent is singular or "
            "indefinite there (a mechanism, an unstable "
            "equilibrium); no period"
        )
    return out


def lowest_of(modes: dict) -> float:
    """The lowest natural frequency at rest from `frequencies`' record; SolverError, saying why,
    where there is none above 0."""
    omega = modes.get("natural_frequencies")
    if not omega:
        raise SolverError(
            f"dynamics: the lowest natural frequency at rest could not be computed "
            f"({modes.get('natural_frequencies_error')}); it sets dynamics.dt and "
            f"dynamics.ramp where they are null"
        )
    if not omega[0] > 0:
        raise SolverError(
            "dynamics: the lowest natural frequency at rest is 0 (a mechanism: the "
            "tangent is singular there); give dynamics.dt and dynamics.ramp"
        )
    return float(omega[0])


def over_time(s, sim, X, d, mat, u_static, out_dir: Path, modes: dict) -> dict:
    """The actuation d applied over time from the start dynamics.start (rest, or the static
    equilibrium under the scene's dead load: nma.dynamics.initial), `modes` the natural
    frequencies at rest (`frequencies`); the trajectory goes to out_dir/trajectory.h5."""
    from ..geometry.validity import StateChecker, summarise
    from ..io.fields import write_trajectory

    density = s.material.density
    omega_1 = lowest_of(modes)
    period_1 = 2 * np.pi / omega_1
    ramp = s.dynamics.ramp if s.dynamics.ramp is not None else period_1
    target = jnp.asarray(d)

    def waveform(coeffs, t):
        return coeffs * (smootherstep(t / ramp) if ramp > 0 else 1.0)

    dyn = sim.dynamics(
        s.dynamics, waveform, density, X=jnp.asarray(X), mat=mat, workers=1, omega_1=omega_1
    )
    t0 = time.perf_counter()
    u, v, info, _ = dyn.run(X, target, mat)
    seconds = time.perf_counter() - t0
    completed = int(info.status) == Status.CONVERGED
    reached = int(info.intervals) + 1  # the states solved, by index (the first at rest)
    states = StateChecker(sim.disc.mesh, np.asarray(X)).check_batch(u[:reached])
    eqs, Xj = sim.equations, jnp.asarray(X)
    kinetic = np.asarray(kinetic_energy(eqs, Xj, v[:reached], density)).tolist()
    quad = quadrature(eqs.solid, Xj)
    strain = [float(strain_energy(eqs.solid, quad, jnp.asarray(ui), mat)) for ui in u[:reached]]
    # a dead load's potential -f . u (the weight's, a traction's), so that kinetic + strain + it is
    # the energy an undamped run conserves where the actuation holds still
    dead = np.asarray(eqs.external_force(quad))
    load = (
        {"load_potential": [float(-dead @ np.asarray(ui).reshape(-1)) for ui in u[:reached]]}
        if np.any(dead)
        else {}
    )
    tracked = {
        k: np.stack([np.asarray(sim.tracked(X, jnp.asarray(ui))[k]) for ui in u[:reached]])
        for k in sim.tracked(X, jnp.asarray(u[0]))
    }
    static = {k: np.asarray(p) for k, p in sim.tracked(X, jnp.asarray(u_static)).items()}
    moved = max(float(np.linalg.norm(static[k] - tracked[k][0])) for k in static) if static else 0.0
    # of the final state, where the trajectory reached it
    lag = (
        max(float(np.linalg.norm(tracked[k][-1] - static[k])) for k in static) / moved
        if completed and static and moved > 0
        else None
    )
    amplification = dynamic_amplification(omega_1, 2.0 * ramp) if ramp > 0 else float("inf")
    said = static_suffices(omega_1, 2.0 * ramp) if ramp > 0 else None
    if said:
        log.warning("%s", said)
    path = write_trajectory(
        out_dir / "trajectory.h5",
        dyn.times[:reached],
        u[:reached],
        v[:reached],
        {
            "kinetic_energy": kinetic,
            "strain_energy": strain,
            **load,
            **{f"tracked/{k}": p for k, p in tracked.items()},
        },
    )
    o = dyn.options
    return {
        "dynamics": {
            "scheme": o.scheme,
            "controller": o.controller,
            "adjoint": o.adjoint,
            "start": o.start,
            "dt": dyn.dt,
            "steps": dyn.steps,
            "ramp": ramp,
            "completed": completed,
            "time_reached": float(info.time),
            "states_reached": reached,
            "why": None if completed else _why(dyn, info),
            "time_steps": int(info.steps),
            "cut_intervals": int(info.cuts),
            "rejected_steps": int(info.rejected),
            "newton_iterations": int(info.iterations),
            "seconds": seconds,
            "lowest_natural_period": period_1,
            "quasi_static_lag": amplification,
            "static_suffices": said,
            "final_vs_static": lag,
            "valid_states": summarise(states),
            "every_state_physical": completed and all(x.valid for x in states),
            "kinetic_energy_max": max(kinetic),
            "trajectory": str(path),
        }
    }


def _why(dyn, info) -> str:
    """Which time step of a trajectory failed, from and to which time, and why (by its index)."""
    k, cuts, controller = int(info.intervals), dyn.max_cuts, dyn.options.controller
    if controller == "fixed":
        cut = " (dynamics.controller=fixed: not cut)"
    elif controller == "adaptive":
        cut = (
            f", even at the shortest step dt / {2**cuts} (dynamics.max_cuts={cuts}; the "
            f"failed one from t = {float(info.time):.6g})"
        )
    elif cuts:
        cut = (
            f", even cut into {2**cuts} steps (dynamics.max_cuts={cuts}; the failed one from "
            f"t = {float(info.time):.6g})"
        )
    else:
        cut = " (dynamics.max_cuts=0: not cut)"
    return (
        f"time stepping failed: time step {k + 1} of {dyn.steps}, from t = {dyn.times[k]:.6g} "
        f"to {dyn.times[k + 1]:.6g}, did not converge{cut}: {Status.describe(info.status)}; "
        f"states 0 to {k} (t = 0 to {dyn.times[k]:.6g}) solved and checked"
    )
