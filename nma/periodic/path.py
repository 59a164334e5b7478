"""A periodic cell's effective response along a macroscopic load path: `follow`.

```python
from nma.periodic import circular_holes, follow, periodic_cell, square_array, uniaxial
cell = periodic_cell(square_array(2, 2))
params, porosity = circular_holes(cell, 0.5)
path = follow(cell, uniaxial("y", -0.2), steps=20, params=params)
path.poisson, path.P[:, 3], path.critical      # Poisson's ratio, nominal stress, the bifurcation
```
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .. import checks
from ..errors import ConfigError
from ..geometry.validity import StateChecker
from .cell import PeriodicCell
from .load import IDENTITY, MacroLoad
from .problem import PeriodicProblem
from .solve import NEGATIVE, NewtonSettings, PathResult, correct, leave_saddle, predict


def _checked_steps(steps) -> int:
    if (
        isinstance(steps, bool)
        or not isinstance(steps, (int, np.integer))
        or not 1 <= steps <= 10000
    ):
        raise ConfigError(f"steps must be an integer in [1, 10000], got {steps!r}")
    return int(steps)


def follow(
    cell: PeriodicCell,
    load: MacroLoad,
    steps: int = 20,
    params=None,
    mat=None,
    stability: bool = True,
    escape: bool = True,
    settings: NewtonSettings | None = None,
    check_states: bool = True,
    points=None,
) -> PathResult:
    """Follow `load` from F_bar = I to its target, reporting at `steps` equally spaced points.

    Args:
        cell: The periodic cell.
        load: The macroscopic load (nma.periodic.load: uniaxial, biaxial, shear).
        steps: Output points along the path (each reached by one or more load steps).
        params: The design (None: the scene's initial one).
        mat: The material's parameters (None: the cell's).
        stability: Compute the reduced Hessian's lowest eigenvalue at every converged load step
            (PeriodicProblem.lowest_modes) and detect a bifurcation where it turns negative.
        escape: Past a bifurcation, leave the saddle along the unstable mode (needs stability).
        settings: Newton's settings.
        check_states: Run nma.geometry.validity's checks on every output state.
        points: The reference control points in place of params' (a design map's output, such
            as a network's); checked to match across the periodic edges.

    Returns:
        The PathResult; a path that cannot go on (an increment cut below min_increment) ends early
        with completed False and its message.
    """
    steps, s = _checked_steps(steps), settings or NewtonSettings()
    if points is None:
        X = cell.reference_points(params)
    else:
        X = jnp.asarray(points, float)
        cell.check_matching(np.asarray(X))
    mat = checks.material_input(cell.material_params if mat is None else mat, cell.disc.material)
    p = PeriodicProblem(cell, X, mat, load)
    checker = StateChecker(cell.disc.mesh, np.asarray(X)) if check_states else None
    z = np.zeros(p.nz)
    z[p.nw :] = np.asarray(load.at(0.0))[p.free]
    E, g, K, K_full = p.linearise(z, load.at(0.0))
    k_ref = p.stiffness_scale(K)
    tol = s.rtol * k_ref * p.length
    lowest_prev, t_prev_conv = np.inf, 0.0
    if stability:
        lowest_prev = float(p.lowest_modes(K)[0][0]) / k_ref
    out = {k: [] for k in ("t", "F", "P", "energy", "valid", "min_J", "lowest", "u", "z")}
    problems, critical = [], None
    t, dt, n_steps, cuts, message = 0.0, 1.0 / steps, 0, 0, ""
    for k in range(1, steps + 1):
        target = k / steps
        while t < target - 1e-12:
            h = min(dt, target - t)
            Fp, Fn = load.at(t), load.at(t + h)
            dz, a = predict(p, z, Fp, Fn - Fp, K_full, K)
            trial = t + a * h
            c = correct(p, z + a * dz, load.at(trial), tol, k_ref, s)
            if not c.converged or a * h < 1e-3 * s.min_increment:
                dt, cuts = 0.5 * h, cuts + 1
                if dt < s.min_increment:
                    message = (
                        f"the load step from t = {t:.4g} could not converge down to an increment "
                        f"of {s.min_increment:g} (last residual {c.rnorm:.3g}, tolerance {tol:.3g})"
                    )
                    break
                continue
            z, t, n_steps = c.z, trial, n_steps + 1
            dt = min(h * (s.grow if c.iterations <= s.max_iters // 3 else 1.0), 1.0)
            K, K_full = c.K, c.K_full
            if stability:
                vals, modes = p.lowest_modes(K)
                lowest = float(vals[0]) / k_ref
                if lowest < -NEGATIVE:
                    if critical is None:
                        frac = lowest_prev / (lowest_prev - lowest) if lowest_prev > 0 else 0.0
                        t_c = t_prev_conv + frac * (t - t_prev_conv)
                        critical = {
                            "t": t_c,
                            "strain": float(load.at(t_c)[load.axial] - IDENTITY[load.axial]),
                            "lowest_before": lowest_prev,
                            "lowest_after": lowest,
                            "mode_u": p.mode_displacement(modes[:, 0]),
                        }
                    if escape:
                        z, K, K_full = _escape(
                            p, z, load.at(t), modes[:, 0], vals[0], k_ref, tol, s, (K, K_full)
                        )
                        lowest = float(p.lowest_modes(K)[0][0]) / k_ref
                        if lowest < -NEGATIVE:  # still a saddle: not a state the cell stays in
                            message = (
                                f"the path could not leave the saddle at t = {t:.4g} along its "
                                f"unstable mode (lowest eigenvalue {lowest:.3g} of the stiffness "
                                "scale after the escape): the buckled branch was not reached"
                            )
                            break
                lowest_prev, t_prev_conv = lowest, t
        if message:
            break
        _record(out, p, z, load.at(t), t, lowest_prev if stability else np.nan)
        if checker is not None:
            v = checker.check(out["u"][-1])
            out["valid"][-1], out["min_J"][-1] = v.valid, v.min_J
            if not v.valid:
                problems.append((t, v.problems()))
    return _result(out, load, n_steps, cuts, message, critical, problems)


def _escape(p, z, Fp, mode, curvature, k_ref, tol, s, Ks):
    """Leave a saddle (up to three times) and settle; the state, its reduced Hessian and full
    stiffness."""
    K, K_full = Ks
    for _ in range(3):
        moved, ok = leave_saddle(p, z, Fp, mode, curvature)
        if not ok:
            break
        c = correct(p, moved, Fp, tol, k_ref, s)
        if not c.converged:
            break
        z, K, K_full = c.z, c.K, c.K_full
        vals, modes = p.lowest_modes(K)
        if vals[0] / k_ref >= -NEGATIVE:
            break
        mode, curvature = modes[:, 0], vals[0]
    return z, K, K_full


def _record(out, p: PeriodicProblem, z, Fp, t, lowest):
    out["t"].append(t)
    out["F"].append(np.asarray(p.F(z, Fp)))
    out["P"].append(p.average_stress(z, Fp))
    out["energy"].append(p.energy(z, Fp) / p.cell.area)
    out["u"].append(p.displacement(z, Fp))
    out["z"].append(np.array(z))
    out["valid"].append(True)
    out["min_J"].append(np.nan)
    out["lowest"].append(lowest)


def _result(out, load: MacroLoad, steps, cuts, message, critical, problems) -> PathResult:
    arr = {k: np.asarray(v, float) for k, v in out.items() if k != "valid"}
    F = arr["F"].reshape(-1, 4)
    axial = F[:, load.axial] - IDENTITY[load.axial]
    lateral = (
        F[:, load.lateral] - IDENTITY[load.lateral]
        if load.lateral is not None
        else np.full(len(F), np.nan)
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        poisson = np.where(axial != 0, -lateral / axial, np.nan)
    # from rest (0, 0) through the path's points
    ax, lat = np.concatenate([[0.0], axial]), np.concatenate([[0.0], lateral])
    incremental = -np.gradient(lat, ax)[1:] if len(F) else np.zeros(0)
    return PathResult(
        t=arr["t"],
        F=F,
        P=arr["P"].reshape(-1, 4),
        energy=arr["energy"],
        strain_axial=axial,
        strain_lateral=lateral,
        poisson=poisson,
        poisson_incremental=incremental,
        valid=np.asarray(out["valid"], bool),
        min_J=arr["min_J"],
        lowest=arr["lowest"],
        u=arr["u"],
        z=arr["z"],
        steps=steps,
        cuts=cuts,
        completed=not message,
        message=message,
        critical=critical,
        problems=problems,
        axial=load.axial,
    )
