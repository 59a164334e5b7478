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

from ..mechanics.energy import quadrature, strain_energy
from ..solver.status import Status
from .mass import mass_blocks
from .modes import dynamic_amplification, natural_frequencies, static_suffices
from .schemes import _apply
from .trajectory import Dynamics
from .waveform import smootherstep

log = logging.getLogger("nma.simulate")
FREQUENCIES = 3  # natural frequencies reported


def frequencies(sim, X, mat, density, d, u) -> dict:
    """The lowest natural frequencies (rad per unit time) and periods of small vibrations about (d, u)."""
    u_free = jnp.asarray(np.asarray(u).reshape(-1)[np.asarray(sim.equations.free)])
    omega = natural_frequencies(sim, jnp.asarray(X), mat, density, FREQUENCIES, d, u_free)
    return {"natural_frequencies": omega.tolist(), "natural_periods": (2 * np.pi / omega).tolist()}


def over_time(s, sim, X, d, mat, u_static, out_dir: Path) -> dict:
    """The actuation d applied over time from rest; the trajectory goes to out_dir/trajectory.h5."""
    from ..geometry.validity import StateChecker, summarise

    density = s.material.density
    omega_1 = float(natural_frequencies(sim, jnp.asarray(X), mat, density, count=1)[0])
    period_1 = 2 * np.pi / omega_1
    ramp = s.dynamics.ramp if s.dynamics.ramp is not None else period_1
    target = jnp.asarray(d)

    def waveform(coeffs, t):
        return coeffs * (smootherstep(t / ramp) if ramp > 0 else 1.0)

    dyn = Dynamics.from_settings(sim, s.dynamics, density, waveform, jnp.asarray(X), mat, workers=1)
    t0 = time.perf_counter()
    u, v, info, _ = dyn.run(X, target, mat)
    seconds = time.perf_counter() - t0
    reached = int(np.searchsorted(dyn.times, float(info.time), side="right"))  # states solved (the first at rest)
    states = StateChecker(sim.disc.mesh, np.asarray(X)).check_batch(u[:reached])
    quad = quadrature(sim.equations.solid, jnp.asarray(X))
    M, edofs = mass_blocks(sim.equations.solid, quad, density), sim.equations.edofs[:sim.equations.elements]
    kinetic = [float(0.5 * vi.reshape(-1) @ np.asarray(_apply(M, edofs, jnp.asarray(vi.reshape(-1))))) for vi in v[:reached]]
    strain = [float(strain_energy(sim.equations.solid, quad, jnp.asarray(ui), mat)) for ui in u[:reached]]
    tracked = {k: np.stack([np.asarray(sim.tracked(X, jnp.asarray(ui))[k]) for ui in u[:reached]])
               for k in sim.tracked(X, jnp.asarray(u[0]))}
    static = {k: np.asarray(p) for k, p in sim.tracked(X, jnp.asarray(u_static)).items()}
    moved = max(float(np.linalg.norm(static[k] - tracked[k][0])) for k in static) if static else 0.0
    lag = max(float(np.linalg.norm(tracked[k][-1] - static[k])) for k in static) / moved if static and moved > 0 else None
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
        "scheme": s.dynamics.scheme, "dt": dyn.dt, "steps": dyn.steps, "ramp": ramp, "completed": int(info.status) == 1,
        "time_reached": float(info.time), "why": None if int(info.status) == 1 else
        f"the step at time {float(info.time):.6g} failed after {s.dynamics.max_cuts} cuts: {Status.describe(info.status)}",
        "time_steps": int(info.steps), "cut_intervals": int(info.cuts),
        "newton_iterations": int(info.iterations), "seconds": seconds,
        "lowest_natural_period": period_1, "quasi_static_lag": amplification, "static_suffices": said,
        "final_vs_static": lag, "valid_states": summarise(states), "every_state_physical": all(x.valid for x in states),
        "kinetic_energy_max": max(kinetic), "trajectory": str(out_dir / "trajectory.h5")}}
