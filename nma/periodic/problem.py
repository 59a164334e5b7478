"""The reduced equations of a periodic cell under a macroscopic load: the unknowns z = (w, f), the
free fluctuation w of the reduced points and F_bar's free components f; the energy E(z; F_p), its
gradient and Hessian in z, assembled from the element tangents of nma.mechanics.energy by the linear
map T: u = T z + (the prescribed components' affine field).

The existing Newton (nma.solver) is tied to a Dirichlet/free split of the control points' dofs and
to 18 x 18 element blocks: F_bar's free components couple to every element, which its sparse
pattern has no room for, so the periodic solver (nma.periodic.solve) drives its own Newton on these
equations, with the engine's energy, tangents, J > 0 step bounds and validity checks.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..mechanics.energy import energy_force_tangents, quadrature, step_bounds, strain_energy
from ..solver.assembly import element_dofs
from .cell import PeriodicCell
from .load import MacroLoad


STEP_FRACTION = 0.9  # of the way to det F = 0 or to the walls' impact: the solver's steps
DENSE_BELOW = 200  # unknowns below which the lowest eigenvalue is found by a dense decomposition
SHIFT = 1e-2  # the shift-invert's sigma, over the largest diagonal entry (lowest_modes)


class PeriodicProblem:
    """A periodic cell with a design X (reference control points) and material parameters `mat`,
    under a load whose free components of F_bar are `load.free`."""

    def __init__(self, cell: PeriodicCell, X, mat, load: MacroLoad):
        self.cell, self.load = cell, load
        self.solid = cell.disc.solid
        self.free = np.asarray(load.free, dtype=np.int64)
        self.nw = len(cell.w_dofs)
        self.nz = self.nw + len(self.free)
        self.X = jnp.asarray(X)
        # what the compiled functions take besides the state: the design's, the material's
        self.ctx = (self.X, cell.pin_position(self.X), jnp.asarray(mat))
        self.length = float(np.min(cell.period))  # the length scale of the F columns
        self.T = self._map(np.asarray(self.X), np.asarray(self.ctx[1]))
        self.edofs = element_dofs(self.solid)
        # compiled once per cell and set of free components, whatever the design and material
        key = ("periodic", tuple(self.free.tolist()))
        if key not in cell.compiled:
            cell.compiled[key] = self._compile()
        self._fns = cell.compiled[key]

    def _compile(self) -> dict:
        quad = lambda X: quadrature(self.solid, X, check_points=True)

        def lin(z, Fp, ctx):
            E, f, kel = energy_force_tangents(self.solid, quad(ctx[0]), self.u(z, Fp, ctx), ctx[2])
            return E, f, kel.elements, kel.contact, kel.which

        def energy(z, Fp, ctx):
            return strain_energy(self.solid, quad(ctx[0]), self.u(z, Fp, ctx), ctx[2])

        def bound(z, Fp, dz, dFp, ctx):
            u = self.u(z, Fp, ctx)
            du = self.u(dz, dFp, ctx) - self.u(jnp.zeros_like(dz), jnp.zeros(4), ctx)
            # a step of at most 1 / STEP_FRACTION is ever taken along du
            found = jnp.min(
                jnp.stack(step_bounds(self.solid, quad(ctx[0]), u, du, 1.0 / STEP_FRACTION))
            )
            return jnp.where(jnp.isnan(found), 0.0, found)

        def energy_of_F(w_free, Fv, ctx):
            return strain_energy(self.solid, quad(ctx[0]), self._u_of(w_free, Fv, ctx), ctx[2])

        return {
            "lin": jax.jit(lin),
            "energy": jax.jit(energy),
            "bound": jax.jit(bound),
            "stress": jax.jit(jax.grad(energy_of_F, argnums=1)),
            "u": jax.jit(self.u),
        }

    # -- the map from the unknowns to the displacement -----------------------------------------
    def F(self, z, Fp):
        """F_bar (4,): the prescribed values Fp with the free components from z."""
        return jnp.asarray(Fp).at[self.free].set(z[self.nw :])

    def u(self, z, Fp, ctx=None):
        """The control points' displacement (n_points, 2): (F_bar - I)(X - X_pin) + w."""
        return self._u_of(z[: self.nw], self.F(z, Fp), self.ctx if ctx is None else ctx)

    def _u_of(self, w_free, Fv, ctx):
        X, origin = ctx[0], ctx[1]
        nrp = self.cell.n_reduced_points
        w = jnp.zeros(2 * nrp, w_free.dtype).at[self.cell.w_dofs].set(w_free).reshape(-1, 2)
        H = Fv.reshape(2, 2) - jnp.eye(2)
        return (X - origin) @ H.T + w[self.cell.rep]

    def _map(self, X: np.ndarray, origin: np.ndarray) -> sp.csr_matrix:
        """T (2 n_points, nz): du = T dz (u is affine in z)."""
        n = len(X)
        slot = np.full(2 * self.cell.n_reduced_points, -1)
        slot[self.cell.w_dofs] = np.arange(self.nw)
        dofs = (2 * self.cell.rep[:, None] + np.arange(2)).ravel()
        rows = np.arange(2 * n)
        keep = slot[dofs] >= 0
        r, c, v = [rows[keep]], [slot[dofs][keep]], [np.ones(keep.sum())]
        rel = X - origin
        for k, comp in enumerate(self.free):
            i, j = divmod(int(comp), 2)
            r.append(2 * np.arange(n) + i)
            c.append(np.full(n, self.nw + k))
            v.append(rel[:, j])
        return sp.csr_matrix(
            (np.concatenate(v), (np.concatenate(r), np.concatenate(c))), shape=(2 * n, self.nz)
        )

    # -- the energy and its derivatives --------------------------------------------------------
    def linearise(self, z, Fp):
        """Energy, reduced gradient g (nz,) and reduced Hessian K (nz, nz, sparse) at a state, and
        the full stiffness (2 n_points square, sparse) for the load's coupling."""
        E, f, Ke, Kc, which = (
            np.asarray(a) for a in self._fns["lin"](jnp.asarray(z), jnp.asarray(Fp), self.ctx)
        )
        # the elements' blocks, then the contact blocks of the walls within reach
        live = which >= 0
        dofs = np.concatenate([self.edofs[: len(Ke)], self.edofs[len(Ke) + which[live]]])
        blocks = np.concatenate([Ke, Kc[live]])
        rows = np.repeat(dofs, 18, axis=1).ravel()
        cols = np.tile(dofs, (1, 18)).ravel()
        n = 2 * self.cell.disc.mesh.n_points
        K = sp.csr_matrix((blocks.ravel(), (rows, cols)), shape=(n, n))
        return float(E), self.T.T @ f.reshape(-1), (self.T.T @ K @ self.T).tocsc(), K

    def energy(self, z, Fp) -> float:
        """The cell's strain energy (inf where the state inverts a Gauss point or, with contact,
        where walls have met)."""
        return float(self._fns["energy"](jnp.asarray(z), jnp.asarray(Fp), self.ctx))

    def affine(self, dFp) -> np.ndarray:
        """The displacement (2 n_points,) a change dFp of the prescribed components alone makes."""
        rel = np.asarray(self.X) - np.asarray(self.ctx[1])
        return (rel @ np.asarray(dFp, float).reshape(2, 2).T).reshape(-1)

    def bound(self, z, Fp, dz, dFp=None) -> float:
        """The largest step t along (dz, dFp) that keeps det F > 0 at every Gauss and check
        point and, with contact, the pores' walls apart (exact up to t = 1 / STEP_FRACTION)."""
        dFp = np.zeros(4) if dFp is None else dFp
        return float(self._fns["bound"](*(jnp.asarray(a) for a in (z, Fp, dz, dFp)), self.ctx))

    def average_stress(self, z, Fp) -> np.ndarray:
        """The average first Piola-Kirchhoff stress (4,), (1 / |box|) dE/dF_bar at fixed w: at an
        equilibrium, the average of P over the box's reference area (Hill's lemma)."""
        Fv = self.F(jnp.asarray(z), jnp.asarray(Fp))
        stress = self._fns["stress"](jnp.asarray(z)[: self.nw], Fv, self.ctx)
        return np.asarray(stress) / self.cell.area

    def displacement(self, z, Fp) -> np.ndarray:
        return np.asarray(self._fns["u"](jnp.asarray(z), jnp.asarray(Fp), self.ctx))

    def mode_displacement(self, v) -> np.ndarray:
        """The control points' displacement (n_points, 2) along a direction v (nz,) of the
        unknowns: its fluctuation and, for F's free components, their affine field."""
        zero = np.zeros(self.nz)
        return self.displacement(v, np.zeros(4)) - self.displacement(zero, np.zeros(4))

    def scaled(self, v: np.ndarray) -> np.ndarray:
        """A step v (nz,) with F's free components multiplied by the cell's length: every entry in
        length units (y = D^-1 v, D = diag(1, .., 1 / L))."""
        s = v.copy()
        s[self.nw :] = s[self.nw :] * self.length
        return s

    def force_norm(self, g: np.ndarray) -> float:
        """||D g||: the gradient's norm with F's free components (force x length) divided by the
        cell's length, every entry a force."""
        s = g.copy()
        s[self.nw :] = s[self.nw :] / self.length
        return float(np.linalg.norm(s))

    def stiffness_scale(self, K: sp.spmatrix) -> float:
        """The largest diagonal entry of D K D (a stiffness, force over length)."""
        d = np.ones(self.nz)
        d[self.nw :] = 1.0 / self.length
        return float(np.max(np.abs(K.diagonal() * d * d)))

    def lowest_modes(self, K: sp.spmatrix):
        """The lowest eigenvalue (1,) and its mode (nz, 1) of the reduced Hessian, its F columns
        scaled to length units (D K D, D = diag(1, .., 1 / L)): the eigenvalue's sign is K's
        (Sylvester's law of inertia).  By shift-invert Lanczos about sigma = -SHIFT x the largest
        diagonal entry: the eigenvalue nearest sigma is the lowest wherever the lowest is above
        sigma, and negative wherever it lies between 2 sigma and sigma; one further below could
        be passed over for a positive neighbour nearer sigma, which a path's steps, each starting
        where the lowest was positive, would have to jump across in one step.  Dense below
        DENSE_BELOW unknowns."""
        d = np.ones(self.nz)
        d[self.nw :] = 1.0 / self.length
        Ks = sp.diags(d) @ K @ sp.diags(d)
        Ks = (0.5 * (Ks + Ks.T)).tocsc()
        if self.nz >= DENSE_BELOW:
            sigma = -SHIFT * float(np.max(np.abs(Ks.diagonal())))
            try:
                # a fixed start: ARPACK's random one would pick either of a symmetric cell's
                # mirror-image modes from run to run, and so the branch a path takes
                v0 = np.random.default_rng(0).standard_normal(Ks.shape[0])
                vals, vecs = spla.eigsh(Ks, k=1, sigma=sigma, which="LM", tol=1e-10, v0=v0)
                return vals, d[:, None] * vecs
            except (spla.ArpackNoConvergence, RuntimeError):  # then the dense decomposition
                pass
        vals, vecs = scipy.linalg.eigh(Ks.toarray(), subset_by_index=[0, 0])
        return vals, d[:, None] * vecs
