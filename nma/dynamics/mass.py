"""The consistent mass matrix from the B-spline basis, and Rayleigh damping, as element blocks on
the stiffness matrix's pattern.

M_e[(a, i), (b, j)] = rho * integral_e N_a N_b dA * delta_ij over each Bezier element, by the same
Gauss rule as the stiffness.  A product of two biquadratic functions is biquartic, which 3 points
per direction integrate exactly: the mass is exact at quad_points >= 3 (at 2 it is the rule's
approximation, as the stiffness is).  Damping C = alpha M + beta K_0 with K_0 the tangent at rest: a
constant matrix, so that a time step stays the minimum of a potential.  The kinetic energy is
1/2 v.M v, element by element (element_kinetic): the one every report and task in time uses.
"""

from __future__ import annotations

import jax.numpy as jnp

from ..mechanics.energy import Quadrature, energy_force_tangents, quadrature
from ..mechanics.solid import Solid


def mass_blocks(solid: Solid, quad: Quadrature, density) -> jnp.ndarray:
    """(E, 18, 18) consistent mass blocks, dofs ordered (a, i) -> 2 a + i as the tangent's."""
    N = jnp.asarray(solid.mesh.basis_values)  # (S2, Q, 9)
    scalar = density * jnp.einsum("psq,sqa,sqb->psab", quad.weights, N, N)  # (P, S2, 9, 9)
    blocks = jnp.einsum("psab,ij->psaibj", scalar, jnp.eye(2))
    return blocks.reshape(-1, 18, 18)


def stiffness_at_rest(solid: Solid, quad: Quadrature, mat) -> jnp.ndarray:
    """(E, 18, 18) the element tangents at rest: stiffness-proportional damping's K_0."""
    u0 = jnp.zeros((solid.mesh.n_points, 2), quad.X.dtype)
    return energy_force_tangents(solid, quad, u0, mat)[2].elements


def rayleigh(alpha: float, beta: float, mass, stiffness) -> jnp.ndarray:
    """C = alpha M + beta K_0, element by element."""
    return alpha * mass + beta * stiffness


def element_kinetic(eqs, X, v, density) -> jnp.ndarray:
    """Each element's kinetic energy 1/2 v_e.M_e v_e at velocities v (..., n_points, 2) of the
    design X, eqs the scene's Equations: (..., elements), differentiable in X and v."""
    M = mass_blocks(eqs.solid, quadrature(eqs.solid, X), density)
    v = jnp.asarray(v)
    ve = v.reshape(v.shape[:-2] + (-1,))[..., eqs.edofs[: eqs.elements]]
    return 0.5 * jnp.einsum("...ea,eab,...eb->...e", ve, M, ve)


def kinetic_energy(eqs, X, v, density) -> jnp.ndarray:
    """The kinetic energy 1/2 v.M v at velocities v (..., n_points, 2): (...)."""
    return element_kinetic(eqs, X, v, density).sum(-1)
