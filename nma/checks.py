"""The library's front-door checks: an argument's shape, dtype, count, sign and finiteness, refused
in one line that names the function and the argument and says what is allowed, before any work.

`array` is the check of `Simulator.equilibrium` (and of every function that takes the model's
arrays); `number` and `integer` check a scalar setting against an interval in the config's notation
("(0, inf)", "[0, 1]"), as nma.settings does for a config; `design`, `actuation`, `solve_input`
and `material_input` are the simulator's checks of a design, actuations and a solve's arrays.  A
value traced by JAX is checked for its shape and dtype only: its numbers are not known until it
runs.
"""

from __future__ import annotations

import numbers
from collections.abc import Mapping

import jax
import jax.numpy as jnp
import numpy as np

from .errors import ConfigError
from .settings import in_range


def _shown(shape: tuple) -> str:
    """A shape as Python writes it, an entry None (any length) as n."""
    entries = ["n" if w is None else str(w) for w in shape]
    return "(" + ", ".join(entries) + ("," if len(entries) == 1 else "") + ")"


def array(
    where: str, name: str, value, shape: tuple, float64: bool = False, finite: bool = True
) -> jnp.ndarray:
    """`value` as a JAX array of real numbers of `shape` (an entry None: any length there), finite
    where it is concrete (unless not `finite`); TypeError or ValueError naming `where: name`
    otherwise.  With `float64`, a RuntimeError where JAX has float64 off (nma solves in float64)."""
    try:
        value = jnp.asarray(value)
    except TypeError:
        raise TypeError(
            f"{where}: {name} must be an array of shape {_shown(shape)} of real numbers, "
            f"got {type(value).__name__} {value!r:.80}"
        ) from None
    if len(value.shape) != len(shape) or any(
        w is not None and w != g for w, g in zip(shape, value.shape)
    ):
        raise ValueError(f"{where}: {name} must have shape {_shown(shape)}, got {value.shape}")
    if not (jnp.issubdtype(value.dtype, jnp.floating) or jnp.issubdtype(value.dtype, jnp.integer)):
        raise TypeError(f"{where}: {name} must hold real numbers, got dtype {value.dtype}")
    if float64 and not jax.config.jax_enable_x64:
        raise RuntimeError(
            f"{where}: nma solves in float64, which JAX has off: call "
            "nma.runtime.configure_jax() before any JAX operation"
        )
    # a concrete value is checked here (in numpy: inside a trace a jnp operation would be staged); a
    # traced one's solve ends at once with NONFINITE_INPUT
    concrete = not isinstance(value, jax.core.Tracer)
    if finite and concrete and not np.all(np.isfinite(np.asarray(value))):
        bad = np.argwhere(~np.isfinite(np.asarray(value)))
        got = (
            np.asarray(value).tolist()
            if value.size <= 8
            else f"{len(bad)} entries that are not, the first at {bad[0].tolist()}"
        )
        raise ValueError(f"{where}: {name} must be finite, got {got}")
    return value


def real(where: str, name: str, value, what: str = "a real number") -> float:
    """value as a Python float, or a TypeError naming it (a bool, a string, an array of several)."""
    scalar = (
        hasattr(value, "shape")
        and np.shape(value) == ()
        and np.issubdtype(np.asarray(value).dtype, np.number)
    )
    if isinstance(value, (bool, np.bool_)) or not (isinstance(value, numbers.Real) or scalar):
        raise TypeError(f"{where}: {name} must be {what}, got {type(value).__name__} {value!r:.80}")
    return float(value)


def number(where: str, name: str, value, spec: str = "(-inf, inf)") -> float:
    """`value` as a float: TypeError where it is not a real number, ConfigError (a ValueError) where
    it is not finite or lies outside the interval `spec`; a traced value is returned as it is."""
    if isinstance(value, jax.core.Tracer):
        return value
    x = real(where, name, value, f"a finite number in {spec}")
    if not in_range(x, spec):
        raise ConfigError(f"{where}: {name} must be a finite number in {spec}, got {x!r}")
    return x


def integer(where: str, name: str, value, spec: str = "(-inf, inf)") -> int:
    """`value` as an int (a float of whole value is one): TypeError where it is not a real number,
    ConfigError (a ValueError) where it is not whole or lies outside the interval `spec`."""
    x = real(where, name, value, f"an integer in {spec}")
    if not (np.isfinite(x) and x == int(x) and in_range(x, spec)):
        raise ConfigError(f"{where}: {name} must be an integer in {spec}, got {value!r}")
    return int(x)


# -- the simulator's arguments (nma.simulator.Simulator) -------------------------------------------


def design(params, expected: dict, bounds: dict, scene: str) -> dict:
    """The design parameters `params` as `expected` (init_params()) has them, checked, naming the
    entry: the same keys and shapes, real numbers, and a concrete value finite and inside the
    design's box (`bounds`: key -> (low, high), where training projects them)."""
    if not isinstance(params, Mapping):
        got = f" of shape {np.shape(params)}" if hasattr(params, "shape") else ""
        raise TypeError(
            f"params must be a mapping of the design's parameters {sorted(expected)} "
            f"(as sim.init_params() gives them), got {type(params).__name__}{got}"
        )
    if set(params) != set(expected):
        raise ValueError(
            f"params must have the keys {sorted(expected)} of scene {scene}'s design, "
            f"got {sorted(params)}"
        )
    for key, want in expected.items():
        value = params[key]
        if jnp.shape(value) != want.shape:
            raise ValueError(
                f"params[{key!r}] must have shape {want.shape}, got {jnp.shape(value)}"
            )
        if not jnp.issubdtype(jnp.result_type(value), jnp.floating) and not jnp.issubdtype(
            jnp.result_type(value), jnp.integer
        ):
            raise TypeError(
                f"params[{key!r}] must hold real numbers, got dtype {jnp.result_type(value)}"
            )
        if isinstance(value, jax.core.Tracer):
            continue
        value, (lo, hi) = np.asarray(value, dtype=np.float64), bounds[key]
        if not np.all(np.isfinite(value)):
            raise ValueError(f"params[{key!r}] must be finite")
        if value.min(initial=lo) < lo or value.max(initial=hi) > hi:
            raise ValueError(
                f"params[{key!r}] must lie in [{lo:g}, {hi:g}] (the design's box), "
                f"got values in [{value.min():g}, {value.max():g}]"
            )
    return params


def actuation(d, n: int, scene: str) -> jnp.ndarray:
    """Actuations `d` as a float64 array of the scene's `n` entries, finite; ConfigError otherwise
    (a command's `actuation` setting is checked here too)."""
    try:
        d = jnp.atleast_1d(jnp.asarray(d, dtype=jnp.float64))
    except (TypeError, ValueError):
        raise ConfigError(
            f"actuation must be {n} numbers, got {type(d).__name__} {d!r:.80}"
        ) from None
    if d.shape != (n,):
        raise ConfigError(
            f"actuation must have {n} entries for scene {scene}, got shape {tuple(d.shape)}"
        )
    if not np.all(np.isfinite(np.asarray(d))):
        raise ConfigError(f"actuation must be finite, got {np.asarray(d).tolist()}")
    return d


def solve_input(name: str, value, shape: tuple) -> jnp.ndarray:
    """One of Simulator.equilibrium's arrays, checked as `array` checks it, as float64."""
    return array("equilibrium", name, value, shape, float64=True).astype(jnp.float64)


def material_input(value, material) -> jnp.ndarray:
    """Simulator.equilibrium's material parameters, checked as `array` checks them and, where
    concrete, by the material's own rules (`material.check`: its ranges), as float64."""
    value = array("equilibrium", "mat", value, (material.n_params,), float64=True)
    if not isinstance(value, jax.core.Tracer):
        material.check(np.asarray(value, dtype=np.float64))
    return value.astype(jnp.float64)
