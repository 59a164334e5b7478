"""The discrete equilibrium equations of one scene (Equations: potential, residual, tangents and
their blocks; at a state, its energy, tangents and the adjoint's pullback), one solve's data
(Problem: quadrature, boundary path, material, and in a time step its Inertia) and Newton's iterate
(State)."""

from __future__ import annotations

import copy
import hashlib
import pickle
import threading
import weakref
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..discretise import Discretisation
from ..mechanics.energy import (
    Quadrature,
    Tangents,
    energy_force_tangents,
    quadrature,
    strain_energy,
)
from .assembly import element_dofs


class Inertia(NamedTuple):
    """The quadratic term an implicit time step adds to the potential, 1/2 u.B u - b.u over every
    dof: B the step's inertia and damping (element blocks on the tangent's pattern, (E, 18, 18)), b
    what the previous state leaves (nma.dynamics.schemes).  Its Hessian B joins the element
    tangents, so every safeguard of the static Newton (step bounds, line search, load-step cuts)
    serves a time step as is."""

    blocks: jnp.ndarray  # (E, 18, 18)
    b: jnp.ndarray  # (2 n_points,)

    def energy(self, edofs, u):
        ue = u[edofs]
        return 0.5 * jnp.einsum("ea,eab,eb->", ue, self.blocks, ue) - jnp.dot(self.b, u)

    def force(self, edofs, u):
        return (
            jnp.zeros_like(u).at[edofs].add(jnp.einsum("eab,eb->ea", self.blocks, u[edofs]))
            - self.b
        )


class _Compiled(dict):
    """key -> what was compiled for one discretisation's content (a dict weak references can
    hold)."""


# what was compiled for each discretisation's content, alive while a discretisation with that
# content is (each discretisation holds its content's)
_BY_CONTENT: weakref.WeakValueDictionary = weakref.WeakValueDictionary()
_BY_DISC: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_LOCK = threading.RLock()


def compiled(eqs: "Equations", key, build):
    """What `build()` makes (jitted kernels of these equations) under a hashable `key`, built once
    per discretisation's content: equations built anew on one scene and fidelity (each Simulator
    from a config builds its own) share it, and trace it once."""
    with _LOCK:
        table = _table(eqs)
        if key not in table:
            table[key] = build()
        return table[key]


def _table(eqs: "Equations") -> _Compiled:
    disc = eqs.discretisation()
    if disc is None:  # equations whose discretisation is gone: their own
        return _BY_DISC.setdefault(eqs, _Compiled())
    if disc not in _BY_DISC:
        key = content_key(disc)
        table = None if key is None else _BY_CONTENT.get(key)
        if table is None:
            table = _Compiled()
            if key is not None:
                _BY_CONTENT[key] = table
        _BY_DISC[disc] = table
    return _BY_DISC[disc]


def content_key(disc: Discretisation) -> str | None:
    """A digest of everything a discretisation holds (None where it cannot be pickled: then it
    shares with no other): equal digests, equal equations."""
    try:
        return hashlib.sha256(pickle.dumps(disc, protocol=pickle.HIGHEST_PROTOCOL)).hexdigest()
    except (pickle.PicklingError, AttributeError, TypeError):
        return None


class Equations:
    """The discrete equilibrium equations of one scene: everything Newton and the adjoint need.
    `contact_slots`: the contact blocks a linearisation's Tangents has room for (all where None)."""

    def __init__(self, disc: Discretisation, contact_slots: int | None = None):
        # all the rest follows from it: the key of what is compiled for these equations
        # (compiled), weak so that what was compiled does not keep it alive
        self.discretisation = weakref.ref(disc)
        self.solid, self.boundary = disc.solid, disc.boundary
        self.contact_slots = contact_slots
        self.free = jnp.asarray(disc.boundary.free_dofs)
        self.dirichlet = jnp.asarray(disc.boundary.dirichlet_dofs)
        self.A = jnp.asarray(disc.boundary.actuation_matrix)
        self.f_ext = jnp.asarray(disc.boundary.external_force)
        # numpy's gather: JAX's eager one compiles a program per scene
        self.f_free = jnp.asarray(np.asarray(disc.boundary.external_force)[disc.boundary.free_dofs])
        # the body force per unit reference area (2,), None: none
        self.body = None if disc.body_force is None else jnp.asarray(disc.body_force)
        self.edofs = jnp.asarray(element_dofs(disc.solid))
        self.elements = disc.mesh.elem_points.reshape(-1, 9).shape[0]

    def with_contact_slots(self, slots: int | None) -> "Equations":
        """The same equations, their linearisations with room for `slots` contact blocks."""
        other = copy.copy(self)
        other.contact_slots = slots
        return other

    def external_force(self, quad):
        """The dead load at full load factor (2 n_points,): the tractions' f_ext, and with a body
        force b its consistent nodal forces, integral of N_a b over the reference configuration by
        the energy's quadrature (so they follow the design, through quad's weights)."""
        if self.body is None:
            return self.f_ext
        mesh = self.solid.mesh
        per_element = jnp.einsum("psq,sqa->psa", quad.weights, jnp.asarray(mesh.basis_values))
        area = jnp.zeros(mesh.n_points, per_element.dtype).at[mesh.elem_points].add(per_element)
        return self.f_ext + (area[:, None] * self.body).reshape(-1)

    def external_free(self, quad):
        """The dead load's free rows (f_free without a body force)."""
        return self.f_free if self.body is None else self.external_force(quad)[self.free]

    def full(self, u_free, u_dir):
        """Every control point's displacement from the free DOFs and the prescribed ones."""
        u = jnp.zeros(2 * self.solid.mesh.n_points, u_free.dtype)
        return u.at[self.free].set(u_free).at[self.dirichlet].set(u_dir).reshape(-1, 2)

    def potential(self, quad, u_free, u_dir, load, mat, inertia: Inertia | None = None):
        """Strain energy less the work of the dead load at load factor `load` (a time step's: plus
        its inertia term)."""
        u = self.full(u_free, u_dir)
        potential = strain_energy(self.solid, quad, u, mat) - load * jnp.dot(
            self.external_force(quad), u.reshape(-1)
        )
        if inertia is not None:
            potential = potential + inertia.energy(self.edofs[: self.elements], u.reshape(-1))
        return potential

    def residual(self, quad, u_free, u_dir, load, mat, inertia: Inertia | None = None):
        return jax.grad(self.potential, argnums=1)(quad, u_free, u_dir, load, mat, inertia)

    def linearise(
        self, quad, u_free, u_dir, load, mat, contact_normal=False, inertia: Inertia | None = None
    ):
        """Potential, free residual g_f and Tangents at a state (`contact_normal`: contact's blocks
        of its normal stiffness only, nma.mechanics.contact.force_and_blocks; a time step's
        `inertia`)."""
        u = self.full(u_free, u_dir)
        energy, force, kel = energy_force_tangents(
            self.solid, quad, u, mat, contact_normal, self.contact_slots
        )
        potential = energy - load * jnp.dot(self.external_force(quad), u.reshape(-1))
        force = force.reshape(-1)
        if inertia is not None:
            edofs = self.edofs[: self.elements]
            potential = potential + inertia.energy(edofs, u.reshape(-1))
            force = force + inertia.force(edofs, u.reshape(-1))
            kel = kel._replace(elements=kel.elements + inertia.blocks)
        return potential, force[self.free] - load * self.external_free(quad), kel

    def blocks(self, kel: Tangents):
        """(dofs (B, 18), blocks (B, 18, 18)) of the elements, then of the contact slots (an empty
        slot's block is zero)."""
        contact = self.edofs[self.elements + jnp.maximum(kel.which, 0)]
        return (self.edofs[: self.elements], kel.elements), (contact, kel.contact)

    def curvature(self, kel: Tangents, v_free):
        """v^T K_ff v: the energy's second derivative along the free-dof direction v."""
        v = jnp.zeros(2 * self.solid.mesh.n_points, kel.elements.dtype).at[self.free].set(v_free)
        return sum(jnp.einsum("ea,eab,eb->", v[dofs], K, v[dofs]) for dofs, K in self.blocks(kel))

    def coupling(self, kel: Tangents, u_D):
        """K_fD u_D: the free force produced by moving the Dirichlet dofs by u_D, at fixed free
        dofs."""
        v = jnp.zeros(2 * self.solid.mesh.n_points, kel.elements.dtype).at[self.dirichlet].set(u_D)
        f = jnp.zeros_like(v)
        for dofs, K in self.blocks(kel):
            f = f.at[dofs].add(jnp.einsum("eab,eb->ea", K, v[dofs]))
        return f[self.free]


def energy_at(eqs: Equations, X, d, mat, u_free):
    """The potential energy of a state at full load."""
    return eqs.potential(quadrature(eqs.solid, X), u_free, eqs.A @ d, 1.0, mat)


def tangents_at(eqs: Equations, X, d, mat, u_free):
    """The Tangents at a converged state (the adjoint's matrix)."""
    return energy_force_tangents(
        eqs.solid,
        quadrature(eqs.solid, X),
        eqs.full(u_free, eqs.A @ d),
        mat,
        capacity=eqs.contact_slots,
    )[2]


def pullback(eqs: Equations, X, d, mat, u_free, adjoint):
    """(X, d, mat)_bar = -adjoint^T dR_f/d(X, d, mat) at fixed free displacements."""

    def residual(X, d, mat):
        return eqs.residual(quadrature(eqs.solid, X), u_free, eqs.A @ d, 1.0, mat)

    return jax.vjp(residual, X, d, mat)[1](-adjoint)


class Problem(NamedTuple):
    """What one solve needs besides the state: the design's quadrature, the boundary data, the
    material. The load path runs from the start (load factor 0) to the target (1): the prescribed
    displacements from u_D0 to u_D and the dead load's factor from load0 to 1.  A cold solve starts
    at rest (u_D0 = 0, load0 = 0); a warm one at another sample's equilibrium (its u_D0, the full
    dead load)."""

    quad: Quadrature
    u_D: jnp.ndarray
    mat: jnp.ndarray
    size: jnp.ndarray
    u_D0: jnp.ndarray
    load0: jnp.ndarray
    inertia: Inertia | None = None  # a time step's (nma.dynamics); None: a static solve

    def boundary(self, lam):
        return self.u_D0 + lam * (self.u_D - self.u_D0)

    def load(self, lam):
        return self.load0 + lam * (1.0 - self.load0)


class State(NamedTuple):
    """Newton's iterate and its bookkeeping, through the load steps (built by keyword:
    starts.setup)."""

    u: jnp.ndarray  # the free dofs' displacement
    lam: jnp.ndarray  # the load factor, 0 at the start of the path and 1 at its end
    u_conv: jnp.ndarray  # the last converged load step's u and lam: where a cut returns to
    lam_conv: jnp.ndarray
    dlam: jnp.ndarray  # the load increment
    # the next step is a load step's predictor (else a corrector at fixed load)
    predictor: jnp.ndarray
    shift: jnp.ndarray  # the diagonal shift of the next step's matrix, K + shift I
    it: jnp.ndarray  # iterations so far
    step_it: jnp.ndarray  # corrector iterations in this load step
    steps: jnp.ndarray  # converged load steps
    cuts: jnp.ndarray  # failed load steps (each halved its increment)
    status: jnp.ndarray  # a nma.solver.status.Status
    tol: jnp.ndarray  # the residual that converges the solve (0 until the scales are known)
    k_ref: jnp.ndarray  # the stiffness scale (the largest diagonal entry at rest)
    rnorm: jnp.ndarray  # ||g_f|| at the last linearisation
    history: jnp.ndarray  # rnorm per iteration, nan past the last
    # heavily damped corrector steps (trust region: rejected steps) in a row in this load step
    damped: jnp.ndarray
    shift_memory: jnp.ndarray  # the last diagonal shift that gave a descent direction in this solve
    # the force scale of the full load (the tolerance is rtol times it, plus atol's)
    f_ref: jnp.ndarray
    # since the last converged load step, a step was stopped short by the check points
    inverting: jnp.ndarray
