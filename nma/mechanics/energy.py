"""Quadrature of the strain energy over Bezier elements: energy, internal force, element tangents.

Arrays are laid out (P, S2, Q, ...): patches x elements per patch x Gauss points.  The element
tangent is the F-space form K_e = sum_q w G^T C G (4 x 4 per point), far cheaper than autodiff
Hessians of whole patches.

The Gauss points do not see all of an element: a state can be inverted between them (det F < 0 near
an element's corner or edge) while W is finite at every one, and a coarse model then reaches
equilibria that are not physical objects.  The exact integral of W over the element would be
infinite there. With fidelity.inversion_barrier = J_hat > 0, det F is also evaluated at 4 x 4 check
points of every element (corners included: where nma.geometry.validity samples it) and a barrier
    b(J) = -kappa (1 - J / J_hat)^2 log(J / J_hat)   for J < J_hat,   0 above
(C2 at J_hat, infinite at J = 0: the barrier of incremental potential contact, Li et al. 2020, on J;
kappa, the bulk modulus, is only its scale, whatever material.volumetric)
weighted by a 16th of the element's area joins the energy, and Newton's step bound keeps det F > 0
at the check points too (as it does without the barrier with solver.element_bound, the default).
Where det F >= J_hat at every check point, nothing changes.

Formulations (`material.formulation`, Material.formulation):
- `displacement`: W(F) at every Gauss point.
- `mixed`: the volumetric term k/2 (log J)^2 is evaluated at the element's mean dilatation
      theta_e = (1 / A_e) integral_e J dA   (A_e the element's reference area),
  so the energy is  sum_q w mu/2 (I1 - 2 - 2 log J) + sum_e A_e k/2 (log theta_e)^2, k the
  material's volume coefficient (Material.volume_modulus: kappa or lambda, by
  material.volumetric).  This is the three-field Hu-Washizu functional with pressure and
  dilatation constant on each Bezier element, both condensed element by element (the
  mean-dilatation method, Nagtegaal, Parks & Rice 1974; Simo, Taylor & Pister 1985): one volume
  constraint per element instead of one per Gauss point, so a nearly incompressible material
  (nu -> 0.5) does not lock.  theta_e involves only the element's 9 points, so the tangent keeps
  the element blocks and the sparse pattern of `displacement`; the shear term keeps its
  -mu log J (a compressible Neo-Hookean of bulk modulus ~mu, which cannot lock).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from ..geometry.mesh import Mesh
from . import contact
from .barrier import ipc
from .material import det2, det_roots
from .solid import Solid


class Quadrature(NamedTuple):
    """Reference-configuration data at every Gauss point (depends on the design, not on u)."""

    grads: jnp.ndarray  # (P, S2, Q, 9, 2) dN/dX
    weights: jnp.ndarray  # (P, S2, Q) Gauss weight x det(dX/dxi)
    det: jnp.ndarray  # (P, S2, Q) det(dX/dxi), > 0 for a valid geometry
    check_grads: jnp.ndarray  # (P, S2, 16, 9, 2) dN/dX at the 4 x 4 check points
    check_weights: jnp.ndarray  # (P, S2, 16) a 16th of the element's area at each
    X: jnp.ndarray  # (n_points, 2) the reference control points (for contact)
    walls: contact.Walls | None  # the pores' walls (contact)


def _physical(dN: jnp.ndarray, Xe: jnp.ndarray, skip_degenerate: bool = False):
    """dN/dX (P, S2, Q, 9, 2) and det(dX/dxi) (P, S2, Q) from parametric derivatives dN (S2, Q, 9,
    2). `skip_degenerate`: where det(dX/dxi) <= 0 (a check point at a degenerate corner) dN/dX is
    left finite (its weight is 0); at Gauss points such a reference is invalid and gives non-finite
    values."""
    J0 = jnp.einsum("sqad,psai->psqid", dN, Xe)  # dX_i / dxi_d
    det = det2(J0)
    safe = jnp.where(det > 0, det, 1.0) if skip_degenerate else det
    inv = (
        jnp.stack(
            [
                jnp.stack([J0[..., 1, 1], -J0[..., 0, 1]], -1),
                jnp.stack([-J0[..., 1, 0], J0[..., 0, 0]], -1),
            ],
            -2,
        )
        / safe[..., None, None]
    )
    return jnp.einsum("sqad,psqdj->psqaj", dN, inv), det


def _check_geometry(mesh: Mesh, X: jnp.ndarray):
    """dN/dX (P, S2, 16, 9, 2) and det(dX/dxi) (P, S2, 16) at the 4 x 4 check points of every
    element (finite where the reference map degenerates, with det <= 0 there)."""
    return _physical(jnp.asarray(mesh.check_grads), X[mesh.elem_points], skip_degenerate=True)


def quadrature(solid: Solid, X: jnp.ndarray, check_points: bool = False) -> Quadrature:
    """Physical basis gradients and weights from the reference control points X (n_points, 2); the
    check points' too with the inversion barrier, or where asked (`check_points`: Newton's element
    bound)."""
    Xe = X[solid.mesh.elem_points]  # (P, S2, 9, 2)
    G, det = _physical(jnp.asarray(solid.mesh.basis_grads), Xe)
    if solid.mesh.fidelity.inversion_barrier > 0 or check_points:
        Gc, detc = _check_geometry(solid.mesh, X)
        checks = (Gc, jnp.asarray(solid.mesh.check_weights) * jnp.maximum(detc, 0.0))
    else:  # no check points: nothing to compute (or to differentiate in the adjoint)
        checks = (
            jnp.zeros(det.shape[:2] + (0, 9, 2), X.dtype),
            jnp.zeros(det.shape[:2] + (0,), X.dtype),
        )
    walls = contact.reference_walls(solid.contact, X) if solid.contact else None
    return Quadrature(G, jnp.asarray(solid.mesh.quad_weights) * det, det, *checks, X, walls)


def deformation_gradient(
    mesh: Mesh, quad: Quadrature, u: jnp.ndarray, at_checks: bool = False
) -> jnp.ndarray:
    """F at the Gauss points (P, S2, Q, 2, 2), or at the check points."""
    ue = u[mesh.elem_points]  # (P, S2, 9, 2)
    return jnp.eye(2) + jnp.einsum(
        "psai,psqaj->psqij", ue, quad.check_grads if at_checks else quad.grads
    )


def check_point_dets(mesh: Mesh, X: jnp.ndarray, u: jnp.ndarray):
    """det F at the 4 x 4 check points of every element (P, S2, 16), corners included (where the
    barrier and nma.geometry.validity evaluate it), and where it is defined: False where the
    reference map degenerates (a collapsed corner, whose barrier weight is 0).  Needs no inversion
    barrier."""
    Gc, detX = _check_geometry(mesh, X)
    return det2(jnp.eye(2) + jnp.einsum("psai,psqaj->psqij", u[mesh.elem_points], Gc)), detX > 0


def inversion_penalty(mesh: Mesh, X: jnp.ndarray, u: jnp.ndarray, margin: float) -> jnp.ndarray:
    """sum over the check points of max(0, margin - det F)^2: zero while det F >= margin at every
    one, smooth (C1), and growing with how far the material is inverted.  A design objective (a term
    of the training loss), not a term of the energy: it steers the design and its actuations away
    from states that invert, while each equilibrium stays that of the model without it.  It samples
    det F (4 x 4 points an element); whether a state is physical is decided by
    nma.geometry.validity."""
    J, defined = check_point_dets(mesh, X, u)
    return jnp.sum(jnp.where(defined, jnp.maximum(margin - J, 0.0) ** 2, 0.0))


def _barrier(J, j_hat, kappa):
    """b(J), b'(J), b''(J) of the inversion barrier (0 for J >= j_hat; callers keep J > 0)."""
    b, db, ddb = ipc(J / j_hat)
    return [kappa * b, kappa * db / j_hat, kappa * ddb / j_hat**2]


def _mean_dilatation(quad: Quadrature, J: jnp.ndarray):
    """Each element's reference area A_e (P, S2) and mean dilatation theta_e = integral J / A_e."""
    area = jnp.sum(quad.weights, axis=-1)
    return area, jnp.sum(quad.weights * J, axis=-1) / area


def _det_derivatives(F: jnp.ndarray, G: jnp.ndarray):
    """Derivatives of J = det F(u) at points with basis gradients G (..., 9, 2): dJ/du_ai =
    cof(F)_ij G_aj (..., 9, 2), and d2J/du_ai du_bk = cross_ab eps_ik with cross_ab = G_a x G_b
    (..., 9, 9) in 2D."""
    cof = jnp.stack(
        [
            jnp.stack([F[..., 1, 1], -F[..., 1, 0]], -1),
            jnp.stack([-F[..., 0, 1], F[..., 0, 0]], -1),
        ],
        -2,
    )  # dJ/dF
    dJ = jnp.einsum("...ij,...aj->...ai", cof, G)
    cross = G[..., :, None, 0] * G[..., None, :, 1] - G[..., :, None, 1] * G[..., None, :, 0]
    return dJ, cross


EPS = jnp.array([[0.0, 1.0], [-1.0, 0.0]])  # the 2D permutation symbol


def strain_energy(solid: Solid, quad: Quadrature, u: jnp.ndarray, mat: jnp.ndarray) -> jnp.ndarray:
    """Integral of W over the reference domain (and the inversion barrier, and the contact barrier);
    +inf if any Gauss point, or with the barrier any check point, is inverted (J <= 0), or with
    contact a pore's walls have met."""
    F = deformation_gradient(solid.mesh, quad, u)
    mu, kappa = solid.material.moduli(mat)
    mixed = solid.material.mixed
    J = det2(F)
    valid = jnp.all(J > 0)
    safe = jnp.where(J[..., None, None] > 0, F, jnp.eye(2))
    W = solid.material.point_terms(mat, volumetric=not mixed)[0](safe)
    energy = jnp.sum(quad.weights * W)
    if mixed:
        # J of `safe`, without recomputing it
        area, theta = _mean_dilatation(quad, jnp.where(J > 0, J, 1.0))
        k = solid.material.volume_modulus(mat, (mu, kappa))
        energy = energy + jnp.sum(area * 0.5 * k * jnp.log(theta) ** 2)
    j_hat = solid.mesh.fidelity.inversion_barrier
    if j_hat > 0:
        Jc = det2(deformation_gradient(solid.mesh, quad, u, at_checks=True))
        energy = energy + jnp.sum(
            quad.check_weights * _barrier(jnp.where(Jc > 0, Jc, j_hat), j_hat, kappa)[0]
        )
        valid = valid & jnp.all((Jc > 0) | (quad.check_weights == 0))
    if solid.contact:
        # inf: walls met
        energy = energy + contact.energy(solid.contact, quad.walls, quad.X + u, mu)
    return jnp.where(valid, energy, jnp.inf)


def _barrier_terms(mesh: Mesh, quad: Quadrature, u: jnp.ndarray, kappa):
    """Energy, element forces (P, S2, 9, 2) and element tangents (P, S2, 9, 2, 9, 2) of the barrier:
    dJ/du_ai = cof(F)_ij G_aj and d2J/du_ai du_bk = eps_ik (G_a x G_b) in 2D."""
    j_hat = mesh.fidelity.inversion_barrier
    G = quad.check_grads
    F = deformation_gradient(mesh, quad, u, at_checks=True)
    J = det2(F)
    b, db, ddb = _barrier(jnp.where(J > 0, J, j_hat), j_hat, kappa)
    w = quad.check_weights
    # (P, S2, C, 9, 2), (.., 9, 9)
    dJ, cross = _det_derivatives(F, G)
    fe = jnp.einsum("psq,psqai->psai", w * db, dJ)
    Ke = jnp.einsum("psq,psqai,psqbk->psaibk", w * ddb, dJ, dJ) + jnp.einsum(
        "psq,psqab,ik->psaibk", w * db, cross, EPS
    )
    return jnp.sum(w * b), fe, Ke


def _volumetric_terms(quad: Quadrature, F: jnp.ndarray, k):
    """Energy, element forces and element tangents of sum_e A_e U(theta_e), U = k/2 (log
    theta)^2 (the `mixed` formulation): f = A U' dtheta, K = A U'' dtheta dtheta + A U' d2theta,
    where dtheta = integral dJ / A and d2theta = integral d2J / A over the element."""
    w = quad.weights
    area, theta = _mean_dilatation(quad, det2(F))
    dJ, cross = _det_derivatives(F, quad.grads)
    dtheta = jnp.einsum("psq,psqai->psai", w, dJ) / area[..., None, None]
    log = jnp.log(theta)
    dU, ddU = k * log / theta, k * (1.0 - log) / theta**2
    fe = (area * dU)[..., None, None] * dtheta
    Ke = jnp.einsum("ps,psai,psbk->psaibk", area * ddU, dtheta, dtheta) + jnp.einsum(
        "ps,psqab,ik->psaibk", dU, w[..., None, None] * cross, EPS
    )
    return jnp.sum(area * 0.5 * k * log**2), fe, Ke


# Each element's terms pass through per-Gauss-point intermediates (w G^T C alone is 14 KB per
# element at 5 x 5 Gauss points): over a whole scene of 1,000+ elements they outgrow the cache and
# the kernel turns memory-bound.  On a CPU the elements therefore go through in
# chunks that stay in cache (the same arithmetic, to round-off); a GPU takes them all at once.
# `make bench-kernels` measures both.  Below CHUNK_ABOVE of w G^T C (576 bytes a Gauss point: the
# reproductions' coarse fidelities, small scenes) chunks gain nothing measurable and only cost
# compile time.
ELEMENT_CHUNK: int | None = 128  # elements per chunk on a CPU; None: all at once
CHUNK_ABOVE = 8 * 2**20  # bytes


def _element_terms(quad: Quadrature, ue: jnp.ndarray, point_terms):
    """Integral of W (Gauss points only), element forces (P, S2, 9, 2) and element tangents
    (P, S2, 9, 2, 9, 2) from the element displacements ue (P, S2, 9, 2), with the material's W, P
    and dP/dF (Material.point_terms)."""
    energy_density, piola, tangent = point_terms

    def terms(ue, G, w):  # any leading element dimensions
        F = jnp.eye(2) + jnp.einsum("...ai,...qaj->...qij", ue, G)
        W = energy_density(F)
        wG = w[..., None, None] * G
        fe = jnp.einsum("...qij,...qaj->...ai", piola(F), wG)
        H = jnp.einsum("...qaj,...qijkl->...qaikl", wG, tangent(F))
        return jnp.sum(w * W, axis=-1), fe, jnp.einsum("...qaikl,...qbl->...aibk", H, G)

    lead = ue.shape[:2]
    n = lead[0] * lead[1]
    size = n * quad.weights.shape[-1] * 576
    if ELEMENT_CHUNK is None or size <= CHUNK_ABOVE or jax.default_backend() != "cpu":
        energy, fe, Ke = terms(ue, quad.grads, quad.weights)
        return jnp.sum(energy), fe, Ke
    # padded to whole chunks with elements of zero weight and zero gradients (F = I: zero terms), so
    # that one compiled chunk does all
    chunks = -(-n // ELEMENT_CHUNK)

    def split(a):
        a = a.reshape((n,) + a.shape[2:])
        a = jnp.pad(a, [(0, chunks * ELEMENT_CHUNK - n)] + [(0, 0)] * (a.ndim - 1))
        return a.reshape((chunks, ELEMENT_CHUNK) + a.shape[1:])

    energy, fe, Ke = jax.lax.map(
        lambda x: terms(*x), (split(ue), split(quad.grads), split(quad.weights))
    )
    unsplit = lambda a: a.reshape((-1,) + a.shape[2:])[:n].reshape(lead + a.shape[2:])
    return jnp.sum(energy), unsplit(fe), unsplit(Ke)


class Tangents(NamedTuple):
    """The Hessian of the energy as 18 x 18 blocks, dofs ordered (a, i) -> 2 a + i over each block's
    points (Solid.block_points: the Bezier elements', then the contact blocks').  Only the
    contact blocks whose walls are within reach are kept, in the first of a fixed number of
    slots."""

    elements: jnp.ndarray  # (E, 18, 18) every Bezier element's
    contact: jnp.ndarray  # (C, 18, 18) the contact blocks whose walls are near; zero past them
    # (C,) the contact block in each slot (its index among solid.contact's pairs), -1: none
    which: jnp.ndarray
    # () how many contact blocks are near: more than C, some are missing (ask again)
    near: jnp.ndarray

    @property
    def complete(self):
        return self.near <= self.which.shape[-1]


def energy_force_tangents(
    solid: Solid,
    quad: Quadrature,
    u: jnp.ndarray,
    mat: jnp.ndarray,
    contact_normal=False,
    capacity: int | None = None,
):
    """Strain energy, internal force (n_points, 2) and the Tangents, in one pass; with contact
    (solid.contact) its near blocks in `capacity` slots (all blocks where None: never incomplete),
    `contact_normal` their normal stiffness only (nma.mechanics.contact.force_and_blocks).  The
    state must have J > 0 everywhere."""
    mu, kappa = solid.material.moduli(mat)
    mixed = solid.material.mixed
    # the volumetric term at the Gauss points, or per element below
    energy, fe, Ke = _element_terms(
        quad, u[solid.mesh.elem_points], solid.material.point_terms(mat, not mixed)
    )
    if mixed:
        k = solid.material.volume_modulus(mat, (mu, kappa))
        ev, fv, Kv = _volumetric_terms(quad, deformation_gradient(solid.mesh, quad, u), k)
        energy, fe, Ke = energy + ev, fe + fv, Ke + Kv
    if solid.mesh.fidelity.inversion_barrier > 0:
        eb, fb, Kb = _barrier_terms(solid.mesh, quad, u, kappa)
        energy, fe, Ke = energy + eb, fe + fb, Ke + Kb
    force = jnp.zeros((solid.mesh.n_points, 2)).at[solid.mesh.elem_points].add(fe)
    Ke = Ke.reshape(-1, 18, 18)
    if solid.contact:
        ec, fc, Kc, which, near = contact.force_and_blocks(
            solid.contact, quad.walls, quad.X + u, mu, capacity, normal=contact_normal
        )
        energy, force = energy + ec, force + fc
    else:
        Kc, which, near = jnp.zeros((0, 18, 18), Ke.dtype), jnp.zeros(0, int), jnp.asarray(0)
    return energy, force, Tangents(Ke, Kc, which, near)


def force_and_tangents(solid: Solid, quad: Quadrature, u: jnp.ndarray, mat: jnp.ndarray):
    return energy_force_tangents(solid, quad, u, mat)[1:]


def step_bounds(solid: Solid, quad: Quadrature, u: jnp.ndarray, du: jnp.ndarray, horizon=jnp.inf):
    """The three bounds of a step along du: the Gauss points' (det F > 0 at every one), the check
    points' (det F > 0 at every one, where the quadrature has them: the inversion barrier's,
    Newton's element bound; inf without) and the walls' (with contact, the time of impact of a
    pore-wall vertex on a chord; inf without).

    det(F + t dF) = c0 + c1 t + c2 t^2 exactly in 2D, so the material's bounds are smallest positive
    roots. The walls' bound is exact up to `horizon` (a caller that takes min(1, fraction * bound)
    needs no more); beyond it a step is not bounded by contact."""
    du_e = du[solid.mesh.elem_points]
    gauss = _first_root(
        deformation_gradient(solid.mesh, quad, u), jnp.einsum("psai,psqaj->psqij", du_e, quad.grads)
    )
    checks = jnp.asarray(jnp.inf, gauss.dtype)
    if quad.check_grads.shape[2]:
        dF = jnp.einsum("psai,psqaj->psqij", du_e, quad.check_grads)
        Fc = deformation_gradient(solid.mesh, quad, u, at_checks=True)
        skip = (quad.check_weights == 0)[..., None, None]  # where the reference map degenerates
        checks = _first_root(jnp.where(skip, jnp.eye(2), Fc), jnp.where(skip, 0.0, dF))
    walls = (
        contact.time_of_impact(solid.contact, quad.walls, quad.X + u, du, horizon)
        if solid.contact
        else jnp.inf
    )
    return gauss, checks, jnp.asarray(walls, gauss.dtype)


def _first_root(F, dF):
    """The smallest positive t with det(F + t dF) = 0 over all points (inf if none)."""
    return jnp.min(det_roots(F, dF))
