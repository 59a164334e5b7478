"""Sparsity of the free-free Hessian, computed once per scene, and element-to-CSR assembly."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..discretise import Discretisation
from ..mechanics.solid import Solid


def element_dofs(solid: Solid) -> np.ndarray:
    """(E, 18) global dof index of each tangent block's rows (Bezier elements, then contact blocks),
    ordered (a, i) -> 2 a + i."""
    pts = solid.block_points
    return (2 * pts[:, :, None] + np.arange(2)).reshape(-1, 18)


@dataclass(frozen=True, eq=False)
class SparsePattern:
    """CSR pattern of K_ff (upper triangle only if `upper`), and where each element entry lands."""

    n: int
    upper: bool
    indptr: np.ndarray
    indices: np.ndarray
    # ((E + Ec) * 324,) CSR data slot of each block entry; nnz for dropped entries
    scatter: np.ndarray
    diag: np.ndarray  # (n,) data slot of each diagonal entry
    elements: int  # the Bezier elements' blocks; the contact blocks follow them
    # the Bezier elements' entries that land in the pattern (about half with `upper`)...
    kept: np.ndarray
    # ...and their data slots: the sum skips the dropped ones, in the same order
    kept_slots: np.ndarray

    @property
    def nnz(self) -> int:
        return len(self.indices)

    def matrix(self, kel, shift: float = 0.0) -> sp.csr_matrix:
        """K_ff (+ shift I) from Tangents (nma.mechanics.energy), its arrays on the host or not."""
        Ke, Kc, which = (np.asarray(a) for a in kel[:3])
        if not bool(kel.complete):
            raise RuntimeError(
                f"these tangents have room for {len(which)} contact blocks, but {int(kel.near)} "
                f"are near: linearise again with more contact slots"
            )
        data = np.bincount(
            self.kept_slots, weights=Ke.reshape(-1)[self.kept], minlength=self.nnz + 1
        )
        # the contact blocks whose walls are within reach (the others are zero, and not there)
        live = which >= 0
        if live.any():
            slots = self.scatter.reshape(-1, 18 * 18)[self.elements + which[live]]
            data += np.bincount(
                slots.reshape(-1), weights=Kc[live].reshape(-1), minlength=self.nnz + 1
            )
        data = data[: self.nnz]
        if shift:
            data[self.diag] += shift
        return sp.csr_matrix((data, self.indices, self.indptr), shape=(self.n, self.n))


def free_index(disc: Discretisation) -> np.ndarray:
    idx = np.full(2 * disc.mesh.n_points, -1, dtype=np.int64)
    idx[disc.boundary.free_dofs] = np.arange(disc.boundary.n_dofs)
    return idx


def element_entries(disc: Discretisation) -> tuple[np.ndarray, np.ndarray]:
    """Free row and column of every element tangent entry (-1 where a Dirichlet dof is involved)."""
    fdof = free_index(disc)[element_dofs(disc.solid)]  # (E, 18)
    rows = np.broadcast_to(fdof[:, :, None], fdof.shape + (18,)).reshape(-1)
    cols = np.broadcast_to(fdof[:, None, :], fdof.shape[:1] + (18, 18)).reshape(-1)
    return rows, cols


def sparse_pattern(disc: Discretisation, upper: bool) -> SparsePattern:
    n = disc.boundary.n_dofs
    rows, cols = element_entries(disc)
    keep = (rows >= 0) & (cols >= 0)
    if upper:
        keep &= rows <= cols
    keys = rows[keep] * n + cols[keep]
    unique = np.unique(keys)
    scatter = np.full(rows.shape, len(unique), dtype=np.int64)
    scatter[keep] = np.searchsorted(unique, keys)
    r, c = unique // n, unique % n
    indptr = np.concatenate([[0], np.cumsum(np.bincount(r, minlength=n))])
    diag = np.searchsorted(unique, np.arange(n) * n + np.arange(n))
    elements = disc.mesh.elem_points.reshape(-1, 9).shape[0]
    kept = np.flatnonzero(scatter[: elements * 18 * 18] < len(unique))
    return SparsePattern(
        n,
        upper,
        indptr.astype(np.int64),
        c.astype(np.int64),
        scatter,
        diag,
        elements,
        kept,
        scatter[kept],
    )
