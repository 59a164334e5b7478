"""The scales a Newton solve converges against: the force scale f_ref, the stiffness scale k_ref and
the tolerance rtol f_ref + atol k_ref L with its floor, a time step's scales and energy round-off,
and the residual's norm, taken scaled so that a very soft material's does not underflow to 0."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .equations import Equations, Problem
from .options import NewtonOptions


def _scales(eqs: Equations, opts: NewtonOptions, p: Problem, kel):
    """The tolerance, the stiffness scale k_ref and the force scale f_ref, from the element tangents
    at rest: f_ref the norm of the linearised out-of-balance force of the full load, k_ref the
    largest diagonal entry."""
    f_free = eqs.external_free(p.quad)
    f_ref = norm(eqs.coupling(kel, p.u_D) - f_free) + norm(f_free)
    return _tolerance(eqs, opts, p, kel, f_ref)


def _step_scales(eqs: Equations, opts: NewtonOptions, p: Problem, kel, g0):
    """A time step's scales, from its first linearisation (residual g0, tangent kel with the
    inertia's blocks): f_ref the norm of its linearised out-of-balance force at its start (the
    previous state's residual under this step's inertia, and the boundary's move), plus the static
    solve's force scale of the actuation at its end: a step meets at least the test a static solve
    of that actuation meets."""
    f_free = eqs.external_free(p.quad)
    static = norm(eqs.coupling(kel, p.u_D) - f_free) + norm(f_free)
    return _tolerance(eqs, opts, p, kel, norm(g0 + eqs.coupling(kel, p.u_D - p.u_D0)) + static)


def _tolerance(eqs: Equations, opts: NewtonOptions, p: Problem, kel, f_ref):
    """rtol f_ref + atol k_ref size, never below tolerance_floor: a solve converges against a scale
    that cannot vanish."""
    kdiag = jnp.max(
        jnp.stack(
            [
                jnp.max(jnp.abs(jnp.diagonal(K, axis1=1, axis2=2)), initial=0.0)
                for _, K in eqs.blocks(kel)
            ]
        )
    )
    tol = opts.rtol * f_ref + opts.atol * kdiag * p.size
    return jnp.maximum(tol, tolerance_floor(tol.dtype)), kdiag, f_ref


def tolerance_floor(dtype) -> float:
    """The smallest tolerance: a residual below it has round-off (eps of it) under float's smallest
    normal number, so that it cannot be told from 0 (about 1e-292 in float64; every material in its
    ranges has a tolerance far above it)."""
    info = jnp.finfo(dtype)
    return float(info.tiny) / float(info.eps)


EXPONENT_BITS = 0x7FF0000000000000  # a float64's exponent field


def norm(v):
    """||v||_2 without underflow or overflow: v divided by the power of two at or below its largest
    entry, the norm of that times it.  A power of two scales exactly, so wherever jnp.linalg.norm(v)
    neither underflows nor overflows this is the same number, bit for bit; where its squares would
    underflow (forces of a very soft material) it is not 0."""
    if v.dtype != jnp.float64:
        return jnp.linalg.norm(v)
    m = jnp.max(jnp.abs(v), initial=0.0)
    bits = jax.lax.bitcast_convert_type(m, jnp.uint64) & jnp.uint64(EXPONENT_BITS)
    scale = jax.lax.bitcast_convert_type(bits, jnp.float64)
    scale = jnp.where(scale > 0, scale, jnp.finfo(jnp.float64).tiny)  # m subnormal: least normal
    ok = jnp.isfinite(m) & (m > 0)
    return jnp.where(ok, scale * jnp.linalg.norm(jnp.where(ok, v / scale, v)), jnp.linalg.norm(v))


ENERGY_NOISE = 1e-13  # a time step's energy round-off, relative to mu0 x area (see _energy_noise)


def _energy_noise(eqs: Equations, p: Problem):
    """A time step's energy round-off: its strain energy sums terms of order mu0 at every Gauss
    point that cancel to O(strain^2), so at small strains (a small vibration) its round-off, ~1e-16
    mu0 x area, exceeds 1e-12 |E0| and would stall the line search; ENERGY_NOISE mu0 x area bounds
    it.  None for a static solve (its tests as they were)."""
    if p.inertia is None:
        return None
    return ENERGY_NOISE * eqs.solid.material.moduli(p.mat)[0] * jnp.sum(p.quad.weights)
