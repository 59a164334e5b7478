"""Build a scene once: analysis patches, merged control points, Dirichlet groups, free DOFs.

The result is static numpy data (topology, quadrature tables) plus one differentiable function,
`reference_points(params)`, from design parameters to the merged reference control points.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import jax.numpy as jnp
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .bspline import (DESIGN_CTRL, basis_matrix, check_tables, element_tables, gauss_legendre_01, greville,
                      refinement_operator, span_points, span_weights)
from ..errors import ConfigError
from ..mechanics.options import FORMULATIONS
from .design import make_design
from .options import Resolution
from .scene import PatchSceneSpec, SceneSpec


@dataclass(frozen=True, eq=False)
class Discretisation:
    spec: SceneSpec | PatchSceneSpec
    design: object
    fidelity: Resolution
    n_points: int
    patch_points: np.ndarray      # (P, m*m) merged point index of every analysis control point
    representative: np.ndarray    # (n_points,) a flat (patch * m*m + local) index for each point
    elem_points: np.ndarray       # (P, S2, 9) point index of each element function
    basis_values: np.ndarray      # (S2, Q, 9)  same tables for every patch
    basis_grads: np.ndarray       # (S2, Q, 9, 2) parametric derivatives
    quad_weights: np.ndarray      # (S2, Q)
    check_grads: np.ndarray       # (S2, 16, 9, 2) parametric derivatives at the 4 x 4 check points
    check_weights: np.ndarray     # (S2, 16) a 16th of the element's parametric area each
    dirichlet_dofs: np.ndarray    # (nD,) flat dof index point * 2 + component
    actuation_matrix: np.ndarray  # (nD, n_actuations): u_D = A @ d
    free_dofs: np.ndarray         # (nf,)
    external_force: np.ndarray    # (2 n_points,) dead load at full load factor
    tracked: dict = field(default_factory=dict)  # name -> (point indices (m*m,), basis weights (m*m,))
    group_points: dict = field(default_factory=dict)  # group name -> point indices
    contact: object = None  # nma.mechanics.contact.ContactModel: the pores' self-contact; None: no contact
    formulation: str = "displacement"  # the strain energy's treatment of volume change (nma.mechanics.energy)

    @property
    def n_patches(self) -> int:
        return self.patch_points.shape[0]

    @property
    def n_dofs(self) -> int:
        return len(self.free_dofs)

    @property
    def n_actuations(self) -> int:
        return self.actuation_matrix.shape[1]

    @property
    def block_points(self) -> np.ndarray:
        """(E + Ec, 9) the points of every tangent block: the Bezier elements, then the contact blocks."""
        blocks = self.elem_points.reshape(-1, 9)
        return np.concatenate([blocks, self.contact.block_points]) if self.contact else blocks

    def analysis_nets(self, params) -> jnp.ndarray:
        """(P, m, m, 2) analysis control nets: the design nets refined by knot insertion (exact)."""
        R = jnp.asarray(refinement_operator(self.fidelity.ctrl_per_patch, self.fidelity.grading))
        return jnp.einsum("ia,pabd,jb->pijd", R, self.design.nets(params), R)

    def reference_points(self, params) -> jnp.ndarray:
        """(n_points, 2) merged reference control points; differentiable in the design parameters."""
        return self.analysis_nets(params).reshape(-1, 2)[self.representative]

    def init_params(self):
        return self.design.init_params()

    def tracked_points(self, points: jnp.ndarray) -> dict[str, jnp.ndarray]:
        """Positions of the tracked material points for control points `points` (X or X + u)."""
        return {k: jnp.asarray(w) @ points[idx] for k, (idx, w) in self.tracked.items()}

    def material_points(self, patches: np.ndarray, xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n, m*m) point indices and basis weights of the material points at parametric coordinates
        xi (n, 2) of the given patches: positions are einsum("nk,nkd->nd", w, points[idx])."""
        m, g = self.fidelity.ctrl_per_patch, self.fidelity.grading
        B0, B1 = basis_matrix(xi[:, 0], m, grading=g), basis_matrix(xi[:, 1], m, grading=g)
        w = np.einsum("ni,nj->nij", B0, B1).reshape(len(xi), m * m)
        return self.patch_points[np.asarray(patches)], w

    def pore_boundary(self) -> tuple[np.ndarray, np.ndarray]:
        """Material points on the central pore's edge, counter-clockwise from its first ring node: per
        side, the design net's Greville abscissae 0, 1/6, 1/2, 5/6 on the inner edge (where the 5 x 5
        design's control points project onto the curve), 4 M points in all; see material_points."""
        design = self.design
        if not len(getattr(design, "central", ())):
            raise ConfigError(f"scene {self.spec.name} has no central pore")
        first = 4 * len(design.porous)
        along = greville(DESIGN_CTRL)[:-1]
        patches = np.repeat(first + np.arange(len(design.central)), len(along))
        xi = np.stack([np.tile(along, len(design.central)), np.ones(len(patches))], axis=1)
        return self.material_points(patches, xi)


def _on_segment(pts: np.ndarray, seg, tol: float) -> np.ndarray:
    a, b = np.asarray(seg[0], float), np.asarray(seg[1], float)
    ab = b - a
    length2 = ab @ ab
    if length2 == 0.0:  # a point actuator
        return np.linalg.norm(pts - a, axis=1) < tol
    t = np.clip((pts - a) @ ab / length2, 0.0, 1.0)
    return np.linalg.norm(pts - (a + t[:, None] * ab), axis=1) < tol


def _edge_traction(nets: np.ndarray, seg, traction, n_ctrl: int, quad: int, tol: float, grading: float):
    """Consistent nodal forces of a dead traction on every patch edge lying on `seg`."""
    gx, gw = gauss_legendre_01(quad)
    s, w = span_points(n_ctrl, gx, grading).ravel(), span_weights(n_ctrl, gw, grading)
    N, dN = basis_matrix(s, n_ctrl, grading=grading), basis_matrix(s, n_ctrl, 1, grading)
    forces = []
    for p, net in enumerate(nets):
        edges = {"xi0": (net[0, :], (p, np.s_[0, :])), "xi1": (net[-1, :], (p, np.s_[-1, :])),
                 "eta0": (net[:, 0], (p, np.s_[:, 0])), "eta1": (net[:, -1], (p, np.s_[:, -1]))}
        for pts, (pp, sl) in edges.values():
            if _on_segment(pts, seg, tol).all():
                jac = np.linalg.norm(dN @ pts, axis=1)
                f = (N * (w * jac)[:, None]).sum(0)[:, None] * np.asarray(traction)[None, :]
                idx = np.arange(n_ctrl * n_ctrl).reshape(n_ctrl, n_ctrl)[sl]
                forces.append((pp, idx, f))
    return forces


def _locate(nets: np.ndarray, target: np.ndarray, tol: float, grading: float) -> tuple[int, np.ndarray]:
    """Patch and parametric coordinates of a reference point (Newton inversion of each patch map)."""
    m = nets.shape[1]
    basis = lambda x, d=0: basis_matrix(x, m, d, grading)[0]
    lo, hi = nets.min(axis=(1, 2)) - tol, nets.max(axis=(1, 2)) + tol
    candidates = np.flatnonzero(np.all((lo <= target) & (target <= hi), axis=1))  # convex hull property
    for p in candidates:
        net = nets[p]
        xi = np.array([0.5, 0.5])
        for _ in range(30):
            B = [basis(xi[k:k + 1]) for k in range(2)]
            dB = [basis(xi[k:k + 1], 1) for k in range(2)]
            x = np.einsum("i,j,ijd->d", B[0], B[1], net)
            J = np.stack([np.einsum("i,j,ijd->d", dB[0], B[1], net),
                          np.einsum("i,j,ijd->d", B[0], dB[1], net)], axis=1)
            step = np.linalg.lstsq(J, target - x, rcond=None)[0]
            xi = np.clip(xi + step, 0.0, 1.0)
            if np.linalg.norm(step) < 1e-14:
                break
        B = [basis(xi[k:k + 1]) for k in range(2)]
        if np.linalg.norm(np.einsum("i,j,ijd->d", B[0], B[1], net) - target) < tol:
            return int(p), xi
    return -1, np.zeros(2)


def _merge_points(nets: np.ndarray, tol: float):
    """Coincident control points (C0 interfaces) merged, by connected components of pairs closer than
    `tol`: the points (numbered in order of first appearance, so following patch order), a flat
    (patch * m*m + local) index of each, and each patch's point indices (P, m*m)."""
    P, m = nets.shape[:2]
    flat = nets.reshape(-1, 2)
    pairs = np.array(sorted(cKDTree(flat).query_pairs(tol)), dtype=np.int64).reshape(-1, 2)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(flat), len(flat)))
    n_points, labels = connected_components(graph, directed=False)
    first = np.full(n_points, len(flat))
    np.minimum.at(first, labels, np.arange(len(flat)))
    order = np.argsort(first)
    relabel = np.empty(n_points, dtype=np.int64)
    relabel[order] = np.arange(n_points)
    representative = first[order]
    return flat[representative], representative, relabel[labels].reshape(P, m * m)


def _dirichlet(spec: SceneSpec | PatchSceneSpec, points: np.ndarray, tol: float):
    """The prescribed DOFs (flat index point * 2 + component, sorted), the actuation matrix A (u_D = A d)
    and each actuated group's points: groups move with their actuation; pinned points, supports (clamped
    or sliding segments) and clamped edges hold their components at 0, winning over a group they touch."""
    n_act = spec.n_actuations
    rows: dict[int, np.ndarray] = {}
    group_points = {}
    for g in spec.groups:
        idx = np.flatnonzero(_on_segment(points, g.segment, tol))
        if len(idx) == 0:
            raise ConfigError(f"scene {spec.name}: group {g.name} segment {g.segment} holds no control point")
        group_points[g.name] = idx
        for pnt in idx:
            for comp in range(2):
                dof = 2 * pnt + comp
                if dof in rows:
                    raise ConfigError(f"scene {spec.name}: point {points[pnt]} belongs to two groups")
                row = np.zeros(n_act)
                row[g.actuation] = g.direction[comp]
                rows[dof] = row
    fixed = []  # (point, component) held at 0
    if isinstance(spec, SceneSpec):
        tree = cKDTree(points)
        for pin in spec.pinned:
            dist, pnt = tree.query(pin)
            if dist > tol:
                raise ConfigError(f"scene {spec.name}: pinned point {pin} is not a control point")
            fixed += [(pnt, 0), (pnt, 1)]
        for sup in spec.supports:
            fixed += [(pnt, c) for pnt in np.flatnonzero(_on_segment(points, sup.segment, tol)) for c in sup.components]
    else:
        for seg in spec.clamped:
            fixed += [(pnt, c) for pnt in np.flatnonzero(_on_segment(points, seg, tol)) for c in (0, 1)]
    for pnt, comp in fixed:
        rows[2 * pnt + comp] = np.zeros(n_act)
    dirichlet = np.array(sorted(rows), dtype=np.int64)
    return dirichlet, np.array([rows[d] for d in dirichlet]).reshape(len(dirichlet), n_act), group_points


def discretise(spec: SceneSpec | PatchSceneSpec, fidelity=None, contact=None,
               formulation: str = "displacement") -> Discretisation:
    """The analysis model of a scene at a concrete `fidelity` (a Resolution or a setting with its fields: the
    control points and Gauss points per patch, the inversion barrier; fidelity=auto is resolved by the
    command, nma.fidelity.resolve, before it gets here; None: the paper's 5 x 5), with the
    pores' self-contact where `contact` (nma.mechanics.contact.ContactSettings) is given, and the strain
    energy's `formulation` (one of nma.mechanics.options.FORMULATIONS)."""
    if formulation not in FORMULATIONS:
        raise ConfigError(f"material.formulation must be one of {list(FORMULATIONS)}, got {formulation!r}")
    fidelity = Resolution.of(fidelity)
    design = make_design(spec)
    m, quad, g = fidelity.ctrl_per_patch, fidelity.quad_points, fidelity.grading
    R = refinement_operator(m, g)
    # topology from a canonical design (mid radii, corners at rest): which points coincide must not
    # depend on the initial radii, or a radius at a bound would merge a pore's sides into one point
    canonical = np.asarray(design.nets(design.topology_params()))
    nets = np.einsum("ia,pabd,jb->pijd", R, canonical, R)  # (P, m, m, 2)
    tol = 1e-7 * np.ptp(nets.reshape(-1, 2), axis=0).max()
    points, representative, patch_points = _merge_points(nets, tol)
    n_points = len(points)

    local, values, grads, weights = element_tables(m, quad, g)
    _, _, check_grads, check_weights = check_tables(m, g)
    elem_points = patch_points[:, local]  # (P, S2, 9)
    dirichlet, A, group_points = _dirichlet(spec, points, tol)
    free = np.setdiff1d(np.arange(2 * n_points), dirichlet)

    f_ext = np.zeros(2 * n_points)
    for tr in getattr(spec, "tractions", ()):
        for p, idx, f in _edge_traction(nets, tr.segment, tr.traction, m, quad, tol, g):
            pts = patch_points[p][idx.ravel()]
            np.add.at(f_ext, 2 * pts, f[:, 0])
            np.add.at(f_ext, 2 * pts + 1, f[:, 1])

    tracked = {}
    for name, xy in spec.tracked.items():
        patch, xi = _locate(nets, np.asarray(xy, float), tol, g)
        if patch < 0:
            raise ConfigError(f"scene {spec.name}: tracked point {name} at {xy} lies in no patch")
        w = np.einsum("i,j->ij", basis_matrix(xi[:1], m, grading=g)[0], basis_matrix(xi[1:], m, grading=g)[0]).ravel()
        keep = w > 1e-15
        tracked[name] = (patch_points[patch][keep], w[keep])

    disc = Discretisation(
        spec=spec, design=design, fidelity=fidelity, n_points=n_points, patch_points=patch_points,
        representative=representative, elem_points=elem_points, basis_values=values, basis_grads=grads,
        quad_weights=weights, check_grads=check_grads, check_weights=check_weights, dirichlet_dofs=dirichlet,
        actuation_matrix=A, free_dofs=free,
        external_force=f_ext, tracked=tracked, group_points=group_points, formulation=formulation)
    if contact is None:
        return disc
    from ..mechanics.contact import build
    from .outline import oriented_loops

    return replace(disc, contact=build(oriented_loops(disc, points)[1:], points, contact, g))


__all__ = ["Resolution", "Discretisation", "discretise", "DESIGN_CTRL"]
