"""Self-contact of the pores: a barrier between the walls of each pore, in the same Newton and
adjoint.

Without contact a closing pore's walls pass through each other and the solver reports an equilibrium
of a shape that cannot exist.  Here each pore's wall is cut into its quadratic Bezier segments (one
per knot span of a boundary edge), each sampled at `per_span` + 1 vertices; between every two
segments of the same pore that are not neighbours, every vertex of one and every chord of the
other's polyline feel the barrier of incremental potential contact (Li et al. 2020, "Incremental
Potential Contact", Eq. 6) on the squared distance d^2:

    E_c = kappa sum_v w_v sum_e b(d^2(v, e) / d_hat^2),   b(s) = -(s - 1)^2 log s  for s < 1, 0
    above,

w_v the vertex's reference arc length (trapezoid rule), kappa = stiffness * mu * d_hat (two parallel
walls at a gap d << d_hat press on each other with about 4 stiffness mu d_hat / d: each wall's
vertices against the other's chords).  A vertex and a chord closer than EXCLUDED_ARC d_hat along
their wall (in the reference) are one piece of wall, not two that can touch: their term is left out.
b is C2 and exactly 0 beyond d_hat: while every pore is open wider than d_hat the model, its tangent
and its adjoint are those without contact (to round-off: the Hessian's pattern, and so its
factorisation's ordering, has the contact blocks).  b -> inf as the gap closes, and Newton's step
bound adds the time of impact of every vertex on every chord (continuous collision detection: the
step never lets a vertex cross a chord), so no iterate interpenetrates.

Why a barrier between wall curves and not a third medium filling the pores (Bluhm, Sigmund and
Poulios 2021): a third medium stiffens every open pore by its regularised stiffness (the answers
change by O(gamma) before anything touches), while the barrier changes nothing until walls come
within d_hat. Why only within a pore: two different boundaries (two pores, a pore and the outer
boundary) are separated by material, which must itself invert (det F -> 0, where the Neo-Hookean
energy is infinite) before they can meet.  Neighbouring segments are excluded (they share a vertex);
a wall folding onto its own neighbour segment is a kink, which inverts the material at the wall
first.

Each pair of segments is one contact block of 6 control points (12 dofs; 5 where they share one),
padded to the 9 points of a Bezier element so that the Hessian's assembly treats it as one more
element: the sparsity pattern is fixed once per scene (every non-neighbouring pair within each
pore).  The blocks of pairs apart by more than d_hat are exactly zero, so a linearisation returns
only the others, in a fixed number of slots (nma.mechanics.energy.Tangents): while the pores are
open, none.  The walls' segments, arc lengths and broad phase are nma.mechanics.walls's; the
barrier's energy, force, tangent blocks and the time of impact are here.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from .barrier import ipc
from .material import det_roots
from .walls import ContactModel, Walls, _box_gaps, _d2_pairs, _faces, _facing, _over_near, vertices
from .walls import build, reference_walls, smallest_gap  # noqa: F401  (contact's names too)

# a vertex meeting a chord within this fraction beyond its ends meets it (or its neighbour)
PROJECTION_SLACK = 1e-9


def stiffness(model: ContactModel, mu) -> jnp.ndarray:
    return model.settings.stiffness * mu * model.d_hat


# -- energy, force, tangent blocks
# -----------------------------------------------------------------------

_EYE = np.eye(2)


def _end_hessian(k: int) -> np.ndarray:
    """(3, 2, 3, 2) Hessian of |p - z_k|^2 in (p, a, b): 2 (e_0 - e_k)(e_0 - e_k)^T per
    component."""
    v = np.zeros(3)
    v[0], v[k] = 1.0, -1.0
    return 2.0 * np.einsum("z,y,ij->ziyj", v, v, _EYE)


def _line_d2(z):
    """Squared distance from z[0] to the line through z[1], z[2]: cross(b - a, p - a)^2 / |b -
    a|^2."""
    p, a, b = z
    e, r = b - a, p - a
    c = e[0] * r[1] - e[1] * r[0]
    return c * c / jnp.dot(e, e)


def _term_derivatives(z, w, inv_d2, normal=False):
    """Energy, gradient (3, 2) and Hessian (3, 2, 3, 2) of one term, w b(d^2(z[0], [z[1], z[2]]) /
    d_hat^2), in closed form per regime of the point-chord distance: nearest to an end (|p - a|^2 or
    |p - b|^2, constant Hessians) or to the chord's inside (the squared distance to its line).
    `normal` (traced or False): where it holds, the Hessian's normal part only, positive
    semi-definite (force_and_blocks)."""
    p, a, b = z
    e = b - a
    t = jnp.dot(p - a, e) / jnp.maximum(jnp.dot(e, e), 1e-300)
    end = jnp.where(t <= 0.0, 1, 2)
    r = p - jnp.where(t <= 0.0, a, b)
    v = jnp.zeros(3).at[0].set(1.0).at[end].set(-1.0)
    inner = (t > 0.0) & (t < 1.0)
    g_end = 2.0 * v[:, None] * r[None, :]
    H_end = jnp.where(end == 1, _end_hessian(1), _end_hessian(2))
    d2 = jnp.where(inner, _line_d2(z), jnp.dot(r, r))
    g = jnp.where(inner, jax.grad(_line_d2)(z), g_end)
    H = jnp.where(inner, jax.hessian(_line_d2)(z), H_end)
    s = d2 * inv_d2
    b0, b1, b2 = ipc(s)
    gs = g * inv_d2
    ggT = jnp.einsum("zi,yj->ziyj", gs, gs)
    H_term = b2 * ggT + b1 * H * inv_d2
    if normal is not False:
        # with d the distance, grad d = g / 2d and the barrier's curvature along d is (4 s b2 + 2
        # b1) / d_hat^2: that curvature on grad d grad d^T, the rest of b1 H (sliding along the
        # chord, turning it) left out, and nothing where the barrier is concave in d
        along = jnp.maximum(b2 + 0.5 * b1 / jnp.maximum(s, 1e-300), 0.0) * ggT
        H_term = jnp.where(normal, along, H_term)
    return w * b0, w * b1 * gs, w * H_term


def _blocks_energy(model: ContactModel, walls: Walls, v, blocks):
    """The barrier (unit kappa) of the given blocks (-1: none) at wall vertices v, and whether every
    vertex keeps a positive distance from every chord it faces."""
    own, other = _faces(model, blocks)  # (b, 2) segments
    d2 = _d2_pairs(v[own], v[other], jnp)  # (b, 2, k + 1, k)
    acts = (blocks >= 0)[:, None, None, None] & _facing(model, walls, own, other)
    e = jnp.sum(jnp.where(acts, walls.weights[own][..., None] * ipc(d2 / model.d_hat**2)[0], 0.0))
    return e, jnp.all((d2 > 0) | ~acts)


@partial(jax.custom_jvp, nondiff_argnums=(0,))
def energy(model: ContactModel, walls: Walls, x, mu) -> jnp.ndarray:
    """The contact energy at deformed control points x (n_points, 2); +inf where a vertex lies on a
    chord it faces.  (A state whose walls have crossed has a finite energy: Newton never reaches
    one, because its step bound stops every vertex before it meets a chord, time_of_impact.)
    Evaluated on the blocks whose boxes are within d_hat (what the line search calls);
    differentiated (the residual, the adjoint's pullback) as one expression over all blocks, the
    same function, which JAX differentiates twice."""
    v = vertices(model, x)

    def step(acc, blocks):
        e, apart = _blocks_energy(model, walls, v, blocks)
        return acc[0] + e, acc[1] & apart

    e, apart = _over_near(
        model, _box_gaps(model, v) < model.d_hat, step, (jnp.zeros((), x.dtype), jnp.asarray(True))
    )
    return jnp.where(apart, stiffness(model, mu) * e, jnp.inf)


def _energy_everywhere(model: ContactModel, walls: Walls, x, mu) -> jnp.ndarray:
    """`energy` over every block at once (the same value)."""
    e, apart = _blocks_energy(model, walls, vertices(model, x), jnp.arange(model.n_blocks))
    return jnp.where(apart, stiffness(model, mu) * e, jnp.inf)


@energy.defjvp
def _energy_jvp(model, primals, tangents):
    return jax.jvp(partial(_energy_everywhere, model), primals, tangents)


def force_and_blocks(
    model: ContactModel, walls: Walls, x, mu, capacity: int | None = None, normal=False
):
    """Energy, nodal force (n_points, 2) and the tangent blocks of the contact at deformed control
    points x: (energy, force, blocks (C, 18, 18), which (C,), near).  Only blocks whose segments
    come within d_hat contribute, few while the pores are open: only they are differentiated, and
    they alone are returned, in the first of C = `capacity` slots (all blocks where None), `which`
    naming each slot's block (-1: none; dofs ordered as block_points, (a, i) -> 2 a + i) and `near`
    counting them.  The energy and force are complete either way; where near > C the blocks past the
    capacity are left out (the caller asks again with room for them): a fixed shape for a jitted
    program, without the (Ec, 18, 18) array of zeros that every iteration would otherwise write and
    assemble (28,512 blocks of a rotation at 11 x 2, twice the elements' tangents).

    `normal` (a traced bool, or False): the blocks of each term's normal stiffness only, positive
    semi-definite, in place of the exact Hessian.  The exact one has the term b'(s) H(d^2), b' < 0,
    which is indefinite and grows like 1/gap as walls close; Newton's correctors far from
    equilibrium then swing the walls in and out of the barrier (IPC's projected Newton makes each
    term's Hessian positive semi-definite for the same reason, Li et al. 2020).  Newton takes them
    while far from equilibrium and the exact blocks near it (NewtonOptions.contact_exact_below),
    where they converge quadratically; the adjoint always takes the exact ones."""
    k = model.settings.per_span
    basis, seg = jnp.asarray(model.vertex_basis), jnp.asarray(model.segments)
    kappa, inv_d2 = stiffness(model, mu), 1.0 / model.d_hat**2
    n = model.n_blocks
    slots = n if capacity is None else min(capacity, n)

    def step(acc, blocks):
        own, other = _faces(model, blocks)  # (b, 2)
        # every term of a block: its three points (vertex; chord ends) as weights over the block's 6
        # control points (first segment's 3, then the second's)
        vb = basis[own][:, :, :, None, :]  # (b, 2, k + 1, 1, 3)
        # (b, 2, 1, k, 3)
        ab, bb = basis[other][:, :, None, :-1, :], basis[other][:, :, None, 1:, :]
        shape = (len(blocks), 2, k + 1, k, 3)
        zero = jnp.zeros(shape)
        rows = jnp.stack(
            [
                jnp.concatenate([jnp.broadcast_to(vb, shape), zero], -1),
                jnp.concatenate([zero, jnp.broadcast_to(ab, shape)], -1),
                # (b, 2, k+1, k, 3, 6)
                jnp.concatenate([zero, jnp.broadcast_to(bb, shape)], -1),
            ],
            axis=-2,
        )
        # side 1: B's vertices, A's chords
        rows = rows.at[:, 1].set(jnp.roll(rows[:, 1], 3, axis=-1))
        pts = seg[jnp.asarray(model.pairs)[jnp.maximum(blocks, 0)]].reshape(-1, 6)  # (b, 6)
        z = jnp.einsum("bsvezc,bcd->bsvezd", rows, x[pts])
        acts = (blocks >= 0)[:, None, None, None] & _facing(model, walls, own, other)
        w = jnp.where(acts, walls.weights[own][..., None], 0.0)  # (b, 2, k + 1, k)
        flat = lambda a: a.reshape((-1,) + a.shape[4:])  # terms in one axis
        R, Z, W = flat(rows), flat(z), flat(w)
        terms = partial(_term_derivatives, inv_d2=inv_d2, normal=normal)
        # (T,), (T, 3, 2), (T, 3, 2, 3, 2)
        e, gz, Hz = jax.vmap(terms)(Z, W)
        e, gz, Hz = kappa * jnp.sum(e), kappa * gz, kappa * Hz
        per = 2 * (k + 1) * k
        g = jnp.einsum("tzc,tzi->tci", R, gz).reshape(-1, per, 6, 2).sum(1)
        H = jnp.einsum("tzc,tziyj,tyd->tcidj", R, Hz, R).reshape(-1, per, 12, 12).sum(1)
        # the chunk's blocks go to the next free slots (padding: zero blocks named -1; past C:
        # dropped)
        at = acc[4] + jnp.arange(len(blocks))
        return (
            acc[0] + e,
            acc[1].at[pts].add(g),
            acc[2].at[at, :12, :12].set(H, mode="drop"),
            acc[3].at[at].set(blocks, mode="drop"),
            acc[4] + len(blocks),
        )

    init = (
        jnp.zeros((), x.dtype),
        jnp.zeros_like(x),
        jnp.zeros((slots, 18, 18), x.dtype),
        jnp.full(slots, -1, jnp.asarray(model.pairs).dtype),
        jnp.asarray(0),
    )
    near = _box_gaps(model, vertices(model, x)) < model.d_hat
    e, force, K, which, _ = _over_near(model, near, step, init)
    return e, force, K, which, jnp.sum(near)


def time_of_impact(model: ContactModel, walls: Walls, x, dx, horizon=jnp.inf) -> jnp.ndarray:
    """The smallest t in (0, horizon] at which a vertex moving along x + t dx meets a chord it faces
    (inf if none): the vertex is on the chord's line where det[a - p, b - p], quadratic in t,
    vanishes (material.det_roots), and on the chord if its projection falls within it there (to
    round-off: a vertex heading for the joint of two chords must not slip between them).  Blocks
    whose boxes are further apart than horizon times their segments' largest motions cannot meet
    within the horizon: only the others are solved for."""
    v, dv = vertices(model, x), vertices(model, dx)
    speed = jnp.linalg.norm(dv, axis=-1).max(axis=1)  # (Ns,)
    A, B = model.pairs[:, 0], model.pairs[:, 1]
    near = _box_gaps(model, v) <= horizon * (speed[A] + speed[B])

    def step(acc, blocks):
        own, other = _faces(model, blocks)
        p, dp = v[own][:, :, :, None], dv[own][:, :, :, None]  # (b, 2, k + 1, 1, 2)
        a, da = v[other][:, :, None, :-1], dv[other][:, :, None, :-1]  # (b, 2, 1, k, 2)
        b, db = v[other][:, :, None, 1:], dv[other][:, :, None, 1:]
        t = det_roots(
            jnp.stack(jnp.broadcast_arrays(a - p, b - p), -1),
            jnp.stack(jnp.broadcast_arrays(da - dp, db - dp), -1),
        )  # (b, 2, k + 1, k, 2)
        at = lambda z, dz: (
            z[..., None, :] + jnp.where(jnp.isfinite(t), t, 0.0)[..., None] * dz[..., None, :]
        )
        pt, at_, bt = at(p, dp), at(a, da), at(b, db)
        chord = bt - at_
        proj = jnp.sum((pt - at_) * chord, -1) / jnp.maximum(jnp.sum(chord * chord, -1), 1e-300)
        acts = (blocks >= 0)[:, None, None, None] & _facing(model, walls, own, other)
        hit = (
            jnp.isfinite(t)
            & (proj >= -PROJECTION_SLACK)
            & (proj <= 1.0 + PROJECTION_SLACK)
            & (t <= horizon)
            & acts[..., None]
        )
        return jnp.minimum(acc, jnp.min(jnp.where(hit, t, jnp.inf), initial=jnp.inf))

    return _over_near(model, near, step, jnp.asarray(jnp.inf, x.dtype))
