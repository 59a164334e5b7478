"""Fields sampled at material points: s x s parametric points per patch, moving with the material.

Used for the colour nets (digital MNIST), the HDF5/XDMF deformation fields and the figures.
"""

from __future__ import annotations

from functools import lru_cache

import jax
import jax.numpy as jnp
import numpy as np

from .bspline import DESIGN_CTRL, basis_matrix
from .mesh import Mesh


@lru_cache(maxsize=None)
def grid_basis(
    n_ctrl: int, samples: int, grading: float = 1.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tensor basis (s*s, n*n) and its two parametric derivatives at a uniform s x s grid in [0,
    1]^2."""
    t = np.linspace(0.0, 1.0, samples)
    B, dB = basis_matrix(t, n_ctrl, grading=grading), basis_matrix(t, n_ctrl, 1, grading)
    kron = lambda a, b: np.einsum("pi,qj->pqij", a, b).reshape(samples * samples, n_ctrl * n_ctrl)
    return kron(B, B), kron(dB, B), kron(B, dB)


def patch_nets(mesh: Mesh, values: jnp.ndarray) -> jnp.ndarray:
    """(P, m*m, k) per-patch nets of a per-point array (n_points, k)."""
    return values[mesh.patch_points]


def sample_positions(mesh: Mesh, points: jnp.ndarray, samples: int) -> jnp.ndarray:
    """(P, s*s, 2) positions of the material points for control points `points` (X or X + u)."""
    B, _, _ = grid_basis(mesh.fidelity.ctrl_per_patch, samples, mesh.fidelity.grading)
    return jnp.einsum("sk,pkd->psd", B, patch_nets(mesh, points))


def sample_jacobian(mesh: Mesh, X: jnp.ndarray, u: jnp.ndarray, samples: int) -> jnp.ndarray:
    """(P, s*s) det F of the deformation at the material points."""
    _, dxi, deta = grid_basis(mesh.fidelity.ctrl_per_patch, samples, mesh.fidelity.grading)
    grad = lambda v: jnp.stack(
        [jnp.einsum("sk,pkd->psd", D, patch_nets(mesh, v)) for D in (dxi, deta)], -1
    )
    dX, dx = grad(X), grad(X + u)  # (P, s*s, 2, 2): [component, parametric direction]
    det = lambda A: A[..., 0, 0] * A[..., 1, 1] - A[..., 0, 1] * A[..., 1, 0]
    return det(dx) / det(dX)


def sample_colours(colours: jnp.ndarray, samples: int) -> jnp.ndarray:
    """(P, s*s) colour in [0, 1]: sigmoid of the 5 x 5 colour spline of each patch."""
    B, _, _ = grid_basis(DESIGN_CTRL, samples)
    return jax.nn.sigmoid(jnp.einsum("sk,pk->ps", B, colours.reshape(colours.shape[0], -1)))


def quad_cells(n_patches: int, samples: int) -> np.ndarray:
    """(P * (s-1)^2, 4) counter-clockwise quads joining the sample grids (for XDMF and plots)."""
    s = samples
    i, j = np.meshgrid(np.arange(s - 1), np.arange(s - 1), indexing="ij")
    base = (i * s + j).ravel()
    q = np.stack([base, base + s, base + s + 1, base + 1], axis=1)
    return (q[None] + (np.arange(n_patches) * s * s)[:, None, None]).reshape(-1, 4)
