"""A law in the homogeneous incompressible tests a material is characterised by (uniaxial,
equibiaxial and planar tension): their stretches, the nominal stress a tensile test measures,
Drucker's stability along them (a config's check_stable); and the principal stretch range of
deformation gradients."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ... import checks
from ...errors import ConfigError
from ..options import MODES
from .base import Law

INCOMPRESSIBLE = 0.5  # the nu of an incompressible test (Neo-Hookean's mu = E / 3)


def mode_stretches(mode: str, lam):
    """The principal stretches of an incompressible homogeneous deformation of stretch lam along 1:
    uniaxial tension, equibiaxial tension (1 and 2), planar tension (pure shear: 2 held)."""
    if mode == "uniaxial":
        return lam, lam**-0.5, lam**-0.5
    if mode == "biaxial":
        return lam, lam, lam**-2.0
    if mode == "planar":
        return lam, jnp.ones_like(lam), 1.0 / lam
    raise ConfigError(f"mode must be one of {list(MODES)}, got {mode!r}")


def _true_stress(law: Law, p, mode: str, lam):
    """sigma_11 - sigma_33 = lam_1 dpsi/dlam_1 - lam_3 dpsi/dlam_3 (sigma_33 = 0: the free
    direction's pressure)."""
    ls = jnp.stack(mode_stretches(mode, lam))
    q = law.named(p, INCOMPRESSIBLE)
    g = jax.grad(lambda l: law.psi_principal(q, l[0], l[1], l[2]))(ls)
    return ls[0] * g[0] - ls[2] * g[2]


def checked_parameters(where: str, law: Law, p) -> jnp.ndarray:
    """p as the array of `law`'s parameters (Law.names, without nu): TypeError or ConfigError
    naming `where`, the law and what it takes where p is not that many real numbers, finite and in
    their ranges (where concrete)."""
    if not isinstance(law, Law):
        raise TypeError(
            f"{where}: law must be a Law (nma.mechanics.laws.law_of(name)), got "
            f"{type(law).__name__} {law!r:.80}"
        )
    names = ", ".join(law.names)
    takes = f"law {law.name} takes [{names}]"
    try:
        p = checks.array(where, "p", p, (None,))
    except ValueError as e:
        raise ConfigError(f"{e}; {takes}") from None
    if p.shape[0] != len(law.names):
        raise ConfigError(
            f"{where}: p must hold {len(law.names)} parameters, got {p.shape[0]}: {takes}"
        )
    if not isinstance(p, jax.core.Tracer):
        values = dict(zip(law.names, np.asarray(p, dtype=float).tolist()))
        bad = law.out_of_range(values)
        if bad:
            raise ConfigError(
                f"{where}: p = [{names}] must have {bad[0]} in {bad[1]} "
                f"(law {law.name}), got {values[bad[0]]:g}"
            )
    return p


def _checked_mode(where: str, mode) -> str:
    if mode not in MODES:
        raise ConfigError(f"{where}: mode must be one of {list(MODES)}, got {mode!r}")
    return mode


def nominal_stress(law: Law, p, mode: str, lam):
    """The engineering (first Piola) stress along 1 of the incompressible `mode` at stretch lam:
    what a tensile test measures, the force over the undeformed section.  p: the law's parameters
    (Law.names); lam: a positive stretch or an array of them."""
    p, mode = checked_parameters("nominal_stress", law, p), _checked_mode("nominal_stress", mode)
    if not law.volume_term:
        raise ConfigError(
            f"nominal_stress: law {law.name}'s energy has no incompressible limit (nu -> 0.5), "
            "which these tests are of: give it its nu and solve the deformation"
        )
    lam = checks.array("nominal_stress", "lam", jnp.atleast_1d(jnp.asarray(lam, float)), (None,))
    if not isinstance(lam, jax.core.Tracer) and not np.all(np.asarray(lam) > 0):
        raise ConfigError(
            f"nominal_stress: lam must hold positive stretches, got {np.asarray(lam).min():g}"
        )
    return jax.vmap(lambda l: _true_stress(law, p, mode, l) / l)(lam)


def drucker_unstable(law: Law, p, stretches=(0.5, 2.0), samples: int = 201) -> str:
    """'' where d sigma / d log(lambda) > 0 (Drucker's condition for these one-parameter paths) in
    every mode at every stretch in `stretches` (low, high: 0 < low < high); else the first mode
    and stretch where it fails."""
    from ...runtime import configure_jax

    configure_jax()  # float64: a config is checked before any solve has set it
    p = checked_parameters("drucker_unstable", law, p)
    lo, hi = checks.array("drucker_unstable", "stretches", stretches, (2,)).tolist()
    if not 0 < lo < hi:
        raise ConfigError(
            f"drucker_unstable: stretches must be (low, high) with 0 < low < high, got {[lo, hi]}"
        )
    samples = checks.integer("drucker_unstable", "samples", samples, "[2, 1000000]")
    known = law.drucker(lo, hi)
    if known is not None:
        return known
    lam = np.exp(np.linspace(np.log(stretches[0]), np.log(stretches[1]), samples))
    for mode in MODES:
        slope = np.asarray(
            jax.vmap(jax.grad(lambda e: _true_stress(law, p, mode, jnp.exp(e))))(jnp.log(lam))
        )
        bad = np.flatnonzero(~(slope > 0))
        if bad.size:
            at = mode_stretches(mode, jnp.asarray(lam[bad[0]]))
            finite = np.isfinite(float(law.psi_principal(law.named(p, INCOMPRESSIBLE), *at)))
            why = (
                "softens (d sigma / d log stretch <= 0)"
                if finite and np.isfinite(slope[bad[0]])
                else "lies beyond the law's limit (its energy is not finite)"
            )
            return f"{mode} tension at stretch {lam[bad[0]]:.3g} {why}"
    return ""


def check_stable(law: Law, values, stretches=(0.5, 2.0)) -> None:
    """Refuses, in a ConfigError naming material.stretches, parameters `values` (by name) for which
    `law` is not Drucker-stable at principal stretches in `stretches` (drucker_unstable); a law
    stable for all its admissible parameters (`Law.stable`) is not evaluated."""
    if law.stable:
        return
    why = drucker_unstable(law, [float(values[n]) for n in law.names], stretches)
    if why:
        raise ConfigError(
            f"material.parameters {dict(values)}: law {law.name} is not stable "
            f"(Drucker) for principal stretches in material.stretches="
            f"{list(stretches)}: {why}"
        )


def principal_stretch_range(F: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """The smallest and largest in-plane principal stretch over deformation gradients F (..., 2, 2):
    the strain range a state asks of its law (lambda_3 = 1 in plane strain)."""
    C = jnp.einsum("...ki,...kj->...ij", F, F)
    m = 0.5 * (C[..., 0, 0] + C[..., 1, 1])
    r = jnp.sqrt(
        jnp.maximum(m**2 - (C[..., 0, 0] * C[..., 1, 1] - C[..., 0, 1] * C[..., 1, 0]), 0.0)
    )
    return jnp.sqrt(jnp.min(jnp.maximum(m - r, 0.0))), jnp.sqrt(jnp.max(m + r))
