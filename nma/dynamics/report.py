"""What `nma.simulate` says about dynamics: the structure's lowest natural frequencies about the state it
solved, and with `dynamics=newmark|generalised_alpha` the actuation applied over time (rising along a
smootherstep over `dynamics.ramp`, then held): every state's validity, the energies, the tracked points
over time against the static equilibrium, and whether the static model would have sufficed."""
from __future__ import annotations

import logging
import time
from pathlib import Path

import h5py
import jax.numpy as jnp
import numpy as np

from scipy.sparse.linalg import ArpackError

from ..errors import SolverError
from ..mechanics.energy import quadrature, strain_energy
from ..solver.status import Status
from .mass import mass_blocks
from .modes import dynamic_amplification, natural_frequencies, static_suffices
from .schemes import _apply
from .trajectory import Dynamics
from .waveform import smootherstep

log = logging.getLogger("nma.simulate")
FREQUENCIES = 3  # natural frequencies reported


class _ModalFailure(Exception):
    """The modal solve (ARPACK, shift-invert about 0) failed: a tangent singular or nearly so."""


def _modes(sim, X, mat, density, count, d=None, u_free=None):
    try:
        return natural_frequencies(sim, jnp.asarray(X), mat, density, count, d, u_free)
    except ArpackError as err:  # ArpackNoConvergence too
        raise _ModalFailure(f"{type(err).__name__}: {err}") from None
    except RuntimeError as err:
        if type(err) is not RuntimeError:  # JAX's, a solver's: not the modal solve's own
            raise
        raise _ModalFailure(str(err)) from None  # SuperLU: a singular tangent


def frequencies(sim, X, mat, density, d, u) -> dict:
    """The lowest natural frequencies (rad per unit time) and periods of small vibrations about
    (d, u); where the modal solve fails (a singular tangent: a mechanism, a saddle), null and the
    reason, logged."""
    u_free = jnp.asarray(np.asarray(u).reshape(-1)[np.asarray(sim.equations.free)])
    try:
        omega = _modes(sim, X, mat, density, FREQUENCIES, d, u_free)
    except _ModalFailure as err:
        why = f"the natural frequencies about this state could not be computed ({err})"
        log.warning("%s", why)
        return {"natural_frequencies": None, "natural_periods": None,
                "natural_frequencies_error": why}
    with np.errstate(divide="ignore"):  # a frequency of 0 (no stiffness along a mode): no period
        periods = 2 * np.pi / omega
    out = {"natural_frequencies": omega.tolist(), "natural_periods": periods.tolist()}
    if np.any(omega == 0):
        out["natural_frequencies_note"] = ("a frequency of 0: the tangent is singular or "
                                           "indefinite there (a mechanism, an unstable "
                                           "equilibrium); no period")
    return out


def lowest_frequency(sim, X, mat, density) -> float:
    """The lowest natural frequency at rest; SolverError where the modal solve fails."""
    try:
        return float(_modes(sim, X, mat, density, 1)[0])
    except _ModalFailure as err:
        raise SolverError(f"dynamics: the lowest natural frequency at rest could not be computed "
                          f"({err}); it sets dynamics.dt and dynamics.ramp where they are "
                          f"null") from None


def over_time(s, sim, X, d, mat, u_static, out_dir: Path) -> dict:
    """The actuation d applied over time from rest; the trajectory goes to out_dir/trajectory.h5."""
    from ..geometry.validity import StateChecker, summarise

    density = s.material.density
    omega_1 = lowest_frequency(sim, X, mat, density)
    period_1 = 2 * np.pi / omega_1
    ramp = s.dynamics.ramp if s.dynamics.ramp is not None else period_1
    target = jnp.asarray(d)

    def waveform(coeffs, t):
        return coeffs * (smootherstep(t / ramp) if ramp > 0 else 1.0)

    dyn = Dynamics.from_settings(sim, s.dynamics, density, waveform, jnp.asarray(X), mat, workers=1,
                                omega_1=omega_1)
    t0 = time.perf_counter()
    u, v, info, _ = dyn.run(X, target, mat)
    seconds = time.perf_counter() - t0
    completed = int(info.status) == Status.CONVERGED
    reached = int(info.intervals) + 1  # the states solved, by index (the first at rest)
    states = StateChecker(sim.disc.mesh, np.asarray(X)).check_batch(u[:reached])
    quad = quadrature(sim.equations.solid, jnp.asarray(X))
    M, edofs = mass_blocks(sim.equations.solid, quad, density), sim.equations.edofs[:sim.equations.elements]
    kinetic = [float(0.5 * vi.reshape(-1) @ np.asarray(_apply(M, edofs, jnp.asarray(vi.reshape(-1))))) for vi in v[:reached]]
    strain = [float(strain_energy(sim.equations.solid, quad, jnp.asarray(ui), mat)) for ui in u[:reached]]
    tracked = {k: np.stack([np.asarray(sim.tracked(X, jnp.asarray(ui))[k]) for ui in u[:reached]])
               for k in sim.tracked(X, jnp.asarray(u[0]))}
    static = {k: np.asarray(p) for k, p in sim.tracked(X, jnp.asarray(u_static)).items()}
    moved = max(float(np.linalg.norm(static[k] - tracked[k][0])) for k in static) if static else 0.0
    # of the final state, where the trajectory reached it
    lag = max(float(np.linalg.norm(tracked[k][-1] - static[k])) for k in static) / moved \
        if completed and static and moved > 0 else None
    amplification = dynamic_amplification(omega_1, 2.0 * ramp) if ramp > 0 else float("inf")
    said = static_suffices(omega_1, 2.0 * ramp) if ramp > 0 else None
    if said:
        log.warning("%s", said)
    with h5py.File(out_dir / "trajectory.h5", "w") as f:
        f["times"], f["u"], f["v"] = dyn.times[:reached], u[:reached], v[:reached]
        f["kinetic_energy"], f["strain_energy"] = kinetic, strain
        for k, p in tracked.items():
            f[f"tracked/{k}"] = p
    return {"dynamics": {
        "scheme": s.dynamics.scheme, "dt": dyn.dt, "steps": dyn.steps, "ramp": ramp,
        "completed": completed, "time_reached": float(info.time), "states_reached": reached,
        "why": None if completed else _why(dyn, info, s.dynamics.max_cuts),
        "time_steps": int(info.steps), "cut_intervals": int(info.cuts),
        "newton_iterations": int(info.iterations), "seconds": seconds,
        "lowest_natural_period": period_1, "quasi_static_lag": amplification, "static_suffices": said,
        "final_vs_static": lag, "valid_states": summarise(states),
        "every_state_physical": completed and all(x.valid for x in states),
        "kinetic_energy_max": max(kinetic), "trajectory": str(out_dir / "trajectory.h5")}}


def _why(dyn, info, cuts: int) -> str:
    """Which time step of a trajectory failed, from and to which time, and why (by its index)."""
    k = int(info.intervals)  # the failed step's interval: from state k
    cut = (f", even cut into {2 ** cuts} steps (dynamics.max_cuts={cuts}; the failed one from t = "
           f"{float(info.time):.6g})" if cuts else " (dynamics.max_cuts=0: not cut)")
    return (f"time stepping failed: time step {k + 1} of {dyn.steps}, from t = {dyn.times[k]:.6g} "
            f"to {dyn.times[k + 1]:.6g}, did not converge{cut}: {Status.describe(info.status)}; "
            f"states 0 to {k} (t = 0 to {dyn.times[k]:.6g}) solved and checked")
