"""The analysis mesh of a scene: the merged control points, the Bezier elements of every patch and
their quadrature tables (the same for every patch), at one fidelity."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .bspline import basis_matrix, check_tables, element_tables
from .options import Resolution


@dataclass(frozen=True, eq=False)
class Mesh:
    fidelity: Resolution
    n_points: int
    patch_points: np.ndarray  # (P, m*m) merged point index of every analysis control point
    representative: np.ndarray  # (n_points,) a flat (patch * m*m + local) index for each point
    elem_points: np.ndarray  # (P, S2, 9) point index of each element function
    basis_values: np.ndarray  # (S2, Q, 9)  same tables for every patch
    basis_grads: np.ndarray  # (S2, Q, 9, 2) parametric derivatives
    quad_weights: np.ndarray  # (S2, Q)
    check_grads: np.ndarray  # (S2, 16, 9, 2) parametric derivatives at the 4 x 4 check points
    check_weights: np.ndarray  # (S2, 16) a 16th of the element's parametric area each

    @classmethod
    def of(cls, nets: np.ndarray, fidelity: Resolution, tol: float) -> "Mesh":
        """The mesh of analysis nets (P, m, m, 2) at `fidelity`, points closer than `tol` merged."""
        m, quad, g = fidelity.ctrl_per_patch, fidelity.quad_points, fidelity.grading
        points, representative, patch_points = merge_points(nets, tol)
        local, values, grads, weights = element_tables(m, quad, g)
        _, _, check_grads, check_weights = check_tables(m, g)
        return cls(
            fidelity=fidelity,
            n_points=len(points),
            patch_points=patch_points,
            representative=representative,
            elem_points=patch_points[:, local],
            basis_values=values,
            basis_grads=grads,
            quad_weights=weights,
            check_grads=check_grads,
            check_weights=check_weights,
        )

    @property
    def n_patches(self) -> int:
        return self.patch_points.shape[0]

    def material_points(self, patches: np.ndarray, xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n, m*m) point indices and basis weights of the material points at parametric coordinates
        xi (n, 2) of the given patches: positions are einsum("nk,nkd->nd", w, points[idx])."""
        m, g = self.fidelity.ctrl_per_patch, self.fidelity.grading
        B0, B1 = basis_matrix(xi[:, 0], m, grading=g), basis_matrix(xi[:, 1], m, grading=g)
        w = np.einsum("ni,nj->nij", B0, B1).reshape(len(xi), m * m)
        return self.patch_points[np.asarray(patches)], w


def merge_points(nets: np.ndarray, tol: float):
    """Coincident control points (C0 interfaces) merged, by connected components of pairs closer
    than `tol`: the points (numbered in order of first appearance, so following patch order), a flat
    (patch * m*m + local) index of each, and each patch's point indices (P, m*m)."""
    P, m = nets.shape[:2]
    flat = nets.reshape(-1, 2)
    pairs = np.array(sorted(cKDTree(flat).query_pairs(tol)), dtype=np.int64).reshape(-1, 2)
    graph = coo_matrix(
        (np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(flat), len(flat))
    )
    n_points, labels = connected_components(graph, directed=False)
    first = np.full(n_points, len(flat))
    np.minimum.at(first, labels, np.arange(len(flat)))
    order = np.argsort(first)
    relabel = np.empty(n_points, dtype=np.int64)
    relabel[order] = np.arange(n_points)
    representative = first[order]
    return flat[representative], representative, relabel[labels].reshape(P, m * m)
