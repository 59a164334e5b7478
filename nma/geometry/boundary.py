"""The boundary of a scene's model: the prescribed dofs (actuated groups, pins, supports, clamped
edges), the actuation matrix that moves them (u_D = A d), the free dofs, and the dead loads."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from ..errors import ConfigError
from .bspline import basis_matrix, gauss_legendre_01, span_points, span_weights
from .mesh import Mesh
from .scene import PatchSceneSpec, SceneSpec


@dataclass(frozen=True, eq=False)
class Boundary:
    dirichlet_dofs: np.ndarray  # (nD,) flat dof index point * 2 + component
    actuation_matrix: np.ndarray  # (nD, n_actuations): u_D = A @ d
    free_dofs: np.ndarray  # (nf,)
    external_force: np.ndarray  # (2 n_points,) dead load at full load factor
    group_points: dict = field(default_factory=dict)  # actuated group name -> point indices

    @classmethod
    def of(
        cls,
        spec: SceneSpec | PatchSceneSpec,
        mesh: Mesh,
        nets: np.ndarray,
        points: np.ndarray,
        tol: float,
    ) -> "Boundary":
        """The boundary `spec` sets on `mesh`, whose analysis nets and merged points are `nets`,
        `points`."""
        dirichlet, A, group_points = _dirichlet(spec, points, tol)
        f_ext = np.zeros(2 * mesh.n_points)
        m, quad, g = mesh.fidelity.ctrl_per_patch, mesh.fidelity.quad_points, mesh.fidelity.grading
        for tr in getattr(spec, "tractions", ()):
            for p, idx, f in _edge_traction(nets, tr.segment, tr.traction, m, quad, tol, g):
                pts = mesh.patch_points[p][idx.ravel()]
                np.add.at(f_ext, 2 * pts, f[:, 0])
                np.add.at(f_ext, 2 * pts + 1, f[:, 1])
        return cls(
            dirichlet_dofs=dirichlet,
            actuation_matrix=A,
            free_dofs=np.setdiff1d(np.arange(2 * mesh.n_points), dirichlet),
            external_force=f_ext,
            group_points=group_points,
        )

    @property
    def n_actuations(self) -> int:
        return self.actuation_matrix.shape[1]

    @property
    def n_dofs(self) -> int:
        return len(self.free_dofs)


def _on_segment(pts: np.ndarray, seg, tol: float) -> np.ndarray:
    a, b = np.asarray(seg[0], float), np.asarray(seg[1], float)
    ab = b - a
    length2 = ab @ ab
    if length2 == 0.0:  # a point actuator
        return np.linalg.norm(pts - a, axis=1) < tol
    t = np.clip((pts - a) @ ab / length2, 0.0, 1.0)
    return np.linalg.norm(pts - (a + t[:, None] * ab), axis=1) < tol


def _edge_traction(
    nets: np.ndarray, seg, traction, n_ctrl: int, quad: int, tol: float, grading: float
):
    """Consistent nodal forces of a dead traction on every patch edge lying on `seg`."""
    gx, gw = gauss_legendre_01(quad)
    s, w = span_points(n_ctrl, gx, grading).ravel(), span_weights(n_ctrl, gw, grading)
    N, dN = basis_matrix(s, n_ctrl, grading=grading), basis_matrix(s, n_ctrl, 1, grading)
    forces = []
    for p, net in enumerate(nets):
        edges = {
            "xi0": (net[0, :], (p, np.s_[0, :])),
            "xi1": (net[-1, :], (p, np.s_[-1, :])),
            "eta0": (net[:, 0], (p, np.s_[:, 0])),
            "eta1": (net[:, -1], (p, np.s_[:, -1])),
        }
        for pts, (pp, sl) in edges.values():
            if _on_segment(pts, seg, tol).all():
                jac = np.linalg.norm(dN @ pts, axis=1)
                f = (N * (w * jac)[:, None]).sum(0)[:, None] * np.asarray(traction)[None, :]
                idx = np.arange(n_ctrl * n_ctrl).reshape(n_ctrl, n_ctrl)[sl]
                forces.append((pp, idx, f))
    return forces


def _dirichlet(spec: SceneSpec | PatchSceneSpec, points: np.ndarray, tol: float):
    """The prescribed DOFs (flat index point * 2 + component, sorted), the actuation matrix A (u_D =
    A d) and each actuated group's points: groups move with their actuation; pinned points, supports
    (clamped or sliding segments) and clamped edges hold their components at 0, winning over a group
    they touch."""
    n_act = spec.n_actuations
    rows: dict[int, np.ndarray] = {}
    group_points = {}
    for g in spec.groups:
        idx = np.flatnonzero(_on_segment(points, g.segment, tol))
        if len(idx) == 0:
            raise ConfigError(
                f"scene {spec.name}: group {g.name} segment {g.segment} holds no control point"
            )
        group_points[g.name] = idx
        for pnt in idx:
            for comp in range(2):
                dof = 2 * pnt + comp
                if dof in rows:
                    raise ConfigError(
                        f"scene {spec.name}: point {points[pnt]} belongs to two groups"
                    )
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
            fixed += [
                (pnt, c)
                for pnt in np.flatnonzero(_on_segment(points, sup.segment, tol))
                for c in sup.components
            ]
    else:
        for seg in spec.clamped:
            fixed += [
                (pnt, c) for pnt in np.flatnonzero(_on_segment(points, seg, tol)) for c in (0, 1)
            ]
    for pnt, comp in fixed:
        rows[2 * pnt + comp] = np.zeros(n_act)
    dirichlet = np.array(sorted(rows), dtype=np.int64)
    return (
        dirichlet,
        np.array([rows[d] for d in dirichlet]).reshape(len(dirichlet), n_act),
        group_points,
    )
