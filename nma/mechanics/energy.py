"""Quadrature of the strain energy over Bezier elements: energy, internal force, element tangents.

Arrays are laid out (P, S2, Q, ...): patches x elements per patch x Gauss points.  The element
tangent is the F-space form K_e = sum_q w G^T C G with C = dP/dF (4 x 4 per point), far cheaper
than autodiff Hessians of whole patches.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from ..geometry.discretise import Discretisation
from .material import det2, lame, neo_hookean, piola, tangent


class Quadrature(NamedTuple):
    """Reference-configuration data at every Gauss point (depends on the design, not on u)."""
    grads: jnp.ndarray    # (P, S2, Q, 9, 2) dN/dX
    weights: jnp.ndarray  # (P, S2, Q) Gauss weight x det(dX/dxi)
    det: jnp.ndarray      # (P, S2, Q) det(dX/dxi), > 0 for a valid geometry


def quadrature(disc: Discretisation, X: jnp.ndarray) -> Quadrature:
    """Physical basis gradients and weights from the reference control points X (n_points, 2)."""
    Xe = X[disc.elem_points]                                           # (P, S2, 9, 2)
    dN = jnp.asarray(disc.basis_grads)                                 # (S2, Q, 9, 2)
    J0 = jnp.einsum("sqad,psai->psqid", dN, Xe)                        # dX_i / dxi_d
    det = det2(J0)
    inv = jnp.stack([jnp.stack([J0[..., 1, 1], -J0[..., 0, 1]], -1),
                     jnp.stack([-J0[..., 1, 0], J0[..., 0, 0]], -1)], -2) / det[..., None, None]
    G = jnp.einsum("sqad,psqdj->psqaj", dN, inv)                       # dN/dX_j
    return Quadrature(G, jnp.asarray(disc.quad_weights) * det, det)


def deformation_gradient(disc: Discretisation, quad: Quadrature, u: jnp.ndarray) -> jnp.ndarray:
    ue = u[disc.elem_points]                                           # (P, S2, 9, 2)
    return jnp.eye(2) + jnp.einsum("psai,psqaj->psqij", ue, quad.grads)


def strain_energy(disc: Discretisation, quad: Quadrature, u: jnp.ndarray, mat: jnp.ndarray) -> jnp.ndarray:
    """Integral of W over the reference domain; +inf if any Gauss point is inverted (J <= 0)."""
    F = deformation_gradient(disc, quad, u)
    mu, kappa = lame(mat)
    J = det2(F)
    safe = jnp.where(J[..., None, None] > 0, F, jnp.eye(2))
    W = jnp.vectorize(lambda f: neo_hookean(f, mu, kappa), signature="(2,2)->()")(safe)
    return jnp.where(jnp.all(J > 0), jnp.sum(quad.weights * W), jnp.inf)


def energy_force_tangents(disc: Discretisation, quad: Quadrature, u: jnp.ndarray, mat: jnp.ndarray):
    """Strain energy, internal force (n_points, 2) and element tangents (P*S2, 18, 18) in one pass;
    tangent dofs are ordered (a, i) -> 2a + i. The state must have J > 0 everywhere."""
    F = deformation_gradient(disc, quad, u)
    mu, kappa = lame(mat)
    flat = F.reshape(-1, 2, 2)
    W = jax.vmap(neo_hookean, in_axes=(0, None, None))(flat, mu, kappa).reshape(quad.weights.shape)
    Pk = piola(F, mu, kappa)
    C = tangent(F, mu, kappa)
    wG = quad.weights[..., None, None] * quad.grads                    # (P, S2, Q, 9, 2)
    fe = jnp.einsum("psqij,psqaj->psai", Pk, wG)
    force = jnp.zeros((disc.n_points, 2)).at[disc.elem_points].add(fe)
    H = jnp.einsum("psqaj,psqijkl->psqaikl", wG, C)
    Ke = jnp.einsum("psqaikl,psqbl->psaibk", H, quad.grads)
    return jnp.sum(quad.weights * W), force, Ke.reshape(-1, 18, 18)


def force_and_tangents(disc: Discretisation, quad: Quadrature, u: jnp.ndarray, mat: jnp.ndarray):
    return energy_force_tangents(disc, quad, u, mat)[1:]


def max_step(disc: Discretisation, quad: Quadrature, u: jnp.ndarray, du: jnp.ndarray) -> jnp.ndarray:
    """Largest alpha > 0 with det F(u + t du) > 0 for all t in [0, alpha) at every Gauss point.

    det(F + t dF) = c0 + c1 t + c2 t^2 exactly in 2D, so the bound is the smallest positive root."""
    F = deformation_gradient(disc, quad, u)
    dF = jnp.einsum("psai,psqaj->psqij", du[disc.elem_points], quad.grads)
    c0 = det2(F)
    c1 = F[..., 0, 0] * dF[..., 1, 1] + dF[..., 0, 0] * F[..., 1, 1] \
        - F[..., 0, 1] * dF[..., 1, 0] - dF[..., 0, 1] * F[..., 1, 0]
    c2 = det2(dF)
    inf = jnp.inf
    disc_ = c1 * c1 - 4.0 * c2 * c0
    sq = jnp.sqrt(jnp.maximum(disc_, 0.0))
    q = -0.5 * (c1 + jnp.where(c1 >= 0, sq, -sq))
    safe_q = jnp.where(q == 0, 1.0, q)
    small_c2 = jnp.abs(c2) <= 1e-14 * (jnp.abs(c1) + jnp.abs(c0))
    r1 = jnp.where(small_c2, -c0 / jnp.where(c1 == 0, 1.0, c1), q / jnp.where(c2 == 0, 1.0, c2))
    r2 = jnp.where(small_c2, inf, c0 / safe_q)
    r1 = jnp.where((r1 > 0) & ((disc_ >= 0) | small_c2) & ~((c1 == 0) & small_c2), r1, inf)
    r2 = jnp.where((r2 > 0) & (disc_ >= 0) & (q != 0), r2, inf)
    return jnp.min(jnp.minimum(r1, r2))
