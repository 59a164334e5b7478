"""The front door of Dynamics (nma.dynamics.trajectory): its settings on construction and a
trajectory's arrays on each call, each refused in one line that names the argument and what is
allowed (nma.checks, as Simulator.equilibrium's).  The ranges are the config's, declared once
(nma.dynamics.options.RANGES, nma.mechanics.options.DENSITY_RANGE)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .. import checks
from ..errors import ConfigError
from ..mechanics.options import DENSITY_RANGE
from .options import ADJOINTS, CONTROLLERS, RANGES, SCHEMES, STARTS


def ranges() -> dict[str, str]:
    """The intervals of the dynamics' settings, by name: the config's (RANGES, and the material's
    density)."""
    return {**RANGES, "density": DENSITY_RANGE}


def check_dynamics(sim, o, density, waveform, v0, workers, parts) -> None:
    """Refuses Dynamics(...)'s arguments outside their ranges: TypeError or ConfigError naming
    the argument.  `o`: the settings (DynamicsOptions), `parts`: the controller and adjoint given
    (names, or objects of their kinds)."""
    from .adjoints import Adjoint
    from .controllers import Controller

    where, spec = "Dynamics", ranges()
    for name, registry, kind in (
        ("scheme", SCHEMES, None),
        ("controller", CONTROLLERS, Controller),
        ("adjoint", ADJOINTS, Adjoint),
    ):
        value = parts.get(name, getattr(o, name))
        if kind is not None and isinstance(value, kind):
            continue
        if not isinstance(value, str) or value not in registry.names():
            raise ConfigError(f"{where}: {name} must be one of {registry.names()}, got {value!r}")
    if o.start not in STARTS:
        raise ConfigError(f"{where}: start must be one of {list(STARTS)}, got {o.start!r}")
    numbers = [
        ("rho_inf", o.rho_inf),
        ("density", density),
        ("alpha", o.alpha),
        ("beta", o.beta),
        ("rtol", o.rtol),
        ("atol", o.atol),
    ] + ([("dt", o.dt)] if o.dt is not None else [])
    for name, value in numbers:
        checks.number(where, name, value, spec[name])
    weighed = sim.disc.body_density
    if sim.disc.body_force is not None and weighed is not None and float(density) != weighed:
        raise ConfigError(
            f"{where}: density must be the one the scene's weight was made with, "
            f"material.density = {weighed:g}, got {float(density):g}: the mass and the body force "
            "would be of two materials"
        )
    checks.integer(where, "steps", o.steps, spec["steps"])
    checks.integer(where, "max_cuts", o.max_cuts, spec["max_cuts"])
    if o.checkpoints is not None:
        checks.integer(where, "checkpoints", o.checkpoints, spec["checkpoints"])
    if workers is not None:
        checks.integer(where, "workers", workers, "[1, 4096]")
    n_act = sim.n_actuations
    if not callable(waveform):
        raise TypeError(
            f"{where}: waveform must be a function f(coeffs, t) -> the scene's {n_act} "
            "actuations at time t (nma.dynamics.waveform.Fourier), got "
            f"{type(waveform).__name__} {waveform!r:.80}"
        )
    actuators = getattr(waveform, "actuators", None)
    if isinstance(actuators, int) and actuators != n_act:
        raise ConfigError(
            f"{where}: waveform drives {actuators} actuators; scene "
            f"{sim.disc.spec.name} has {n_act}"
        )
    if v0 is not None:
        n = sim.disc.mesh.n_points
        checks.array(where, "v0", v0, (2 * n,) if np.shape(v0) == (2 * n,) else (n, 2))


def check_run(dyn, where: str, X, coeffs, mat, finite: bool = True):
    """(X, coeffs, mat) as float64 arrays, refused (TypeError, ValueError naming the argument) where
    one has another shape or holds other than real numbers, where the coefficients are not the
    waveform's count or it does not give the scene's actuations from them, or where the material is
    out of its law's ranges.  With `finite`, a concrete argument that is not finite is refused too;
    without (or traced), a trajectory from one ends at once with status NONFINITE_INPUT."""
    sim = dyn.sim

    def array(name, value, shape):
        return checks.array(where, name, value, shape, float64=True, finite=finite)

    X_ = array("X", X, (sim.disc.mesh.n_points, 2))
    mat_ = array("mat", mat, (sim.disc.material.n_params,))
    count = getattr(dyn.waveform, "n_coeffs", None)
    coeffs_ = array("coeffs", coeffs, (count if isinstance(count, int) else None,))
    if not isinstance(mat_, jax.core.Tracer) and np.all(np.isfinite(np.asarray(mat_))):
        sim.disc.material.check(np.asarray(mat_, dtype=np.float64), where)
    try:
        out = jax.eval_shape(dyn.waveform, jax.ShapeDtypeStruct(coeffs_.shape, jnp.float64), 0.0)
    except (TypeError, ValueError, IndexError) as e:
        raise ValueError(
            f"{where}: the waveform cannot take coeffs of shape {coeffs_.shape}: "
            f"{str(e).splitlines()[0]}"
        ) from None
    if getattr(out, "shape", None) != (sim.n_actuations,):
        raise ValueError(
            f"{where}: the waveform must give the scene's {sim.n_actuations} "
            f"actuations, got shape {getattr(out, 'shape', type(out).__name__)} from "
            f"coeffs of shape {coeffs_.shape}"
        )
    return tuple(a.astype(jnp.float64) for a in (X_, coeffs_, mat_))


def checked_function(dyn, trajectory):
    """`trajectory(X, coeffs, mat)` (nma.dynamics.backward.differentiable) behind the front
    door: shapes and dtypes checked (under vmap: one sample's), concrete arguments' finiteness and
    the material's ranges too; other real precisions taken as float64."""

    def function(X, coeffs, mat):
        return trajectory(*check_run(dyn, "Dynamics.function", X, coeffs, mat))

    function.__doc__ = trajectory.__doc__
    return function
