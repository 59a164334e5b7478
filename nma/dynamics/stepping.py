"""The jitted pieces of a time step and of its adjoint, for one scene, scheme and damping.

A step's residual, with u_{n+1} = (free u_f, prescribed u_D(t_{n+1})) and the state z_n = (u, v, a),
    R(u_f; z_n, X, mat, u_D) = f(u_{n+1}) + B u_{n+1} - b(z_n) - f_ext        (free rows)
is the static residual with the step's Inertia (nma.dynamics.schemes), the dead load f_ext
(scene.gravity, a traction) at full load in every step, and in b's alpha_f term too (the net force
f(u_n) - f_ext at t_n).  Its adjoint: for cotangents
(u_bar, v_bar, a_bar) of z_{n+1}, the explicit update (v, a)_{n+1} = U(u_{n+1}, z_n) passes its part
on to u_{n+1} and z_n; then lambda = K_eff^-1 u_bar_f with K_eff = K(u_{n+1}) + B, and
(z_n, X, mat, u_D)_bar -= lambda^T dR/d(z_n, X, mat, u_D), u_D also receiving u_bar's prescribed
rows. R depends on the design X through the quadrature and the mass and damping blocks only, which
are the same in every step: the sweep sums their cotangents and pulls the sum back to X once
(design_vjp).
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp

from ..mechanics.energy import quadrature, strain_energy
from ..solver.equations import Equations, compiled
from .initial import has_dead_load
from .mass import mass_blocks, rayleigh, stiffness_at_rest
from .schemes import Scheme


class StepKernels:
    """The jitted pieces: the design's quadrature and matrices, a step's Inertia, the update, the
    adjoint's pieces."""

    @classmethod
    def of(cls, eqs: Equations, scheme: Scheme, density, alpha, beta, waveform) -> "StepKernels":
        """The pieces for these equations, built once per discretisation's content, scheme,
        density, damping and waveform (nma.solver.equations.compiled), so that Dynamics built anew
        on one scene trace them once; a waveform that is not hashable: pieces of their own."""
        build = lambda: cls(eqs, scheme, density, alpha, beta, waveform)
        key = ("time step", scheme, density, alpha, beta, waveform)
        try:
            hash(key)
        except TypeError:
            return build()
        return compiled(eqs, key, build)

    def __init__(
        self, eqs: Equations, scheme: Scheme, density: float, alpha: float, beta: float, waveform
    ):
        self.eqs, self.scheme = eqs, scheme
        design = partial(_design, eqs, scheme, density, alpha, beta)
        self.design = jax.jit(design)
        self.inertia = jax.jit(partial(_inertia_of, eqs, scheme))
        self.update = jax.jit(scheme.update)
        self.full = jax.jit(lambda u_free, d: eqs.full(u_free, eqs.A @ d).reshape(-1))
        self.actuation = jax.jit(waveform)
        self.update_vjp = jax.jit(partial(_update_vjp, scheme))
        self.pullback = jax.jit(partial(_pullback, eqs, scheme))
        self.design_vjp = jax.jit(lambda X, mat, bar: jax.vjp(design, X, mat)[1](bar))
        self.actuation_vjp = jax.jit(
            lambda c, t, d_bar: jax.vjp(lambda c: waveform(c, t), c)[1](d_bar)[0]
        )


def _design(eqs, scheme, density, alpha, beta, X, mat):
    """What a step takes from the design: its quadrature, mass and damping blocks."""
    quad = quadrature(eqs.solid, X)
    M = mass_blocks(eqs.solid, quad, density)
    K0 = stiffness_at_rest(eqs.solid, quad, mat) if beta else jnp.zeros_like(M)
    return quad, M, rayleigh(alpha, beta, M, K0)


def internal_force(eqs: Equations, quad, mat, u, scheme: Scheme | None = None):
    """The strain energy's gradient at u (flat, every dof) less the dead load (scene.gravity, a
    traction), which acts at t_n as at t_{n+1}: the force the scheme weighs by alpha_f; 0 for a
    scheme that does not use it (alpha_f 0)."""
    if scheme is not None and scheme.alpha_f == 0.0:
        return jnp.zeros_like(u)
    f = jax.grad(lambda w: strain_energy(eqs.solid, quad, w.reshape(-1, 2), mat))(u)
    return f - eqs.external_force(quad) if has_dead_load(eqs) else f


def _inertia_of(eqs, scheme, quad, M, C, mat, u, v, a, dt):
    """The step's Inertia from the state at t_n (flat arrays, every dof) and the design's
    quadrature, mass and damping blocks."""
    f_n = internal_force(eqs, quad, mat, u, scheme)
    return scheme.inertia(u, v, a, f_n, M, C, eqs.edofs[: eqs.elements], dt)


def step_residual(eqs, scheme, quad, M, C, mat, u, v, a, u_free_next, u_D_next, dt):
    inertia = _inertia_of(eqs, scheme, quad, M, C, mat, u, v, a, dt)
    return eqs.residual(quad, u_free_next, u_D_next, 1.0, mat, inertia)


def _update_vjp(scheme, u_next, u, v, a, dt, v_bar, a_bar):
    """U's cotangents: (u_next_bar, u_bar, v_bar, a_bar) from those of (v_{n+1}, a_{n+1})."""
    _, vjp = jax.vjp(lambda un, u, v, a: scheme.update(un, u, v, a, dt), u_next, u, v, a)
    return vjp((v_bar, a_bar))


def _pullback(eqs, scheme, design, mat, u, v, a, u_free_next, u_D_next, dt, lam, design_bar):
    """-lambda^T dR/d(design, mat, u, v, a, u_D), the design's part (quadrature, M, C) added to
    the sum design_bar: (design_bar, mat_bar, u_bar, v_bar, a_bar, u_D_bar)."""

    def residual(design, mat, u, v, a, u_D):
        return step_residual(eqs, scheme, *design, mat, u, v, a, u_free_next, u_D, dt)

    bar = jax.vjp(residual, design, mat, u, v, a, u_D_next)[1](-lam)
    return (jax.tree_util.tree_map(jnp.add, design_bar, bar[0]), *bar[1:])
