"""A periodic cell: a scene of k x m cells whose opposite boundaries are tied.

The displacement of every control point is split as u = (F_bar - I)(X - X_pin) + w, with w
periodic: the control points of the right (top) edge carry the fluctuation w of their partners on
the left (bottom) edge, which sit one period L away.  So w is stored once per class of tied points
(the reduced points), w is held at zero at one point (X_pin: rigid translation removed), and
u(X+) - u(X-) = (F_bar - I)(X+ - X-) holds exactly for every pair of tied points.  No support or
actuated group acts: the macroscopic deformation gradient F_bar is the whole load.

The B-spline control points of opposite edges must match for the tie to be exact: a regular grid of
cells makes them match (the pores' outer edges are the straight cell sides, whatever the design's
radii); a scene whose opposite edges carry different cells is refused, naming the point that has no
partner.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from scipy.spatial import cKDTree

from .. import checks
from ..discretise import Discretisation
from ..errors import ConfigError

COMPONENTS = ("F11", "F12", "F21", "F22")  # F_bar's entries, in this order everywhere


def _tie(points: np.ndarray, box: np.ndarray, tol: float, name: str) -> np.ndarray:
    """For every point, the index of the point it is tied to on the left/bottom edges (itself if
    none): right edge points shift by -Lx, top edge points by -Ly (the top-right corner by both).
    ConfigError where a point on an edge has no partner on the opposite edge."""
    (x0, y0), (x1, y1) = box
    L = box[1] - box[0]
    tree = cKDTree(points)
    image = points.copy()
    image[np.abs(points[:, 0] - x1) < tol, 0] -= L[0]
    image[np.abs(points[:, 1] - y1) < tol, 1] -= L[1]
    dist, tied = tree.query(image)
    edges = (("right", "left", 0, x1, -1), ("top", "bottom", 1, y1, -1))
    for side, other, axis, line, sign in edges:
        on = np.abs(points[:, axis] - line) < tol
        bad = np.flatnonzero(on & (dist > tol))
        if len(bad):
            p = points[bad[0]]
            q = p.copy()
            q[axis] += sign * L[axis]
            raise ConfigError(
                f"scene {name}: not periodic: the control point at ({p[0]:.6g}, {p[1]:.6g}) on "
                f"the {side} edge has no partner at ({q[0]:.6g}, {q[1]:.6g}) on the {other} edge "
                "(opposite edges must carry the same cells, '.' where the other has '.')"
            )
    for side, other, axis, line in (("left", "right", 0, x0), ("bottom", "top", 1, y0)):
        on = np.flatnonzero(np.abs(points[:, axis] - line) < tol)
        shifted = points[on].copy()
        shifted[:, axis] += L[axis]
        d, _ = tree.query(shifted)
        if np.any(d > tol):
            p = points[on[np.argmax(d)]]
            raise ConfigError(
                f"scene {name}: not periodic: the control point at ({p[0]:.6g}, {p[1]:.6g}) on "
                f"the {side} edge has no partner on the {other} edge (opposite edges must carry "
                "the same cells)"
            )
    return tied


@dataclass(frozen=True, eq=False)
class PeriodicCell:
    """A scene's discretisation with its periodic tie: what the periodic solver works on.

    Attributes:
        disc: The discretisation (nma.discretise), without boundary conditions of its own.
        material_params: The material's parameter array (nma.resolve.material_params).
        box: ((x0, y0), (x1, y1)), the periodic box; area its area, the homogenised stress's.
        rep: (n_points,) the reduced point each control point is tied to.
        pin: the reduced point whose w is held at zero.
        w_dofs: (nw,) flat dofs (2 * reduced point + component) of the free fluctuation.
        porosity: the scene's pores as circles of this porosity (scene.porosity); None: the
            design its radii_init gives.
    """

    disc: Discretisation
    material_params: Any
    box: np.ndarray
    rep: np.ndarray
    pin: int
    w_dofs: np.ndarray
    tol: float
    porosity: float | None = None
    # the periodic problems' compiled functions (nma.periodic.problem), by load kind
    compiled: dict = field(default_factory=dict)

    @classmethod
    def of(cls, disc: Discretisation, mat, porosity: float | None = None) -> "PeriodicCell":
        """The periodic cell of a discretised grid scene (nma.discretise, no boundary conditions
        needed) with material parameters `mat` and the scene's `porosity` (its initial circles);
        nma.periodic.periodic_cell builds one from settings."""
        spec = disc.spec
        box = np.array(
            [[spec.x_breaks[0], spec.y_breaks[0]], [spec.x_breaks[-1], spec.y_breaks[-1]]], float
        )
        X = np.asarray(disc.reference_points(disc.design.topology_params()))
        tol = 1e-7 * float(np.max(box[1] - box[0]))
        tied = _tie(X, box, tol, spec.name)
        # a chain (top-right -> top-left -> bottom-left) ends at a left/bottom point
        for _ in range(2):
            tied = tied[tied]
        reps, rep = np.unique(tied, return_inverse=True)
        pin_at = np.asarray(spec.pinned[0], float) if spec.pinned else box[0]
        dist, pin_point = cKDTree(X).query(pin_at)
        if spec.pinned and dist > tol:
            raise ConfigError(
                f"scene {spec.name}: pinned point {pin_at.tolist()} is not a control point"
            )
        pin = int(rep[pin_point])
        w_dofs = np.setdiff1d(np.arange(2 * len(reps)), [2 * pin, 2 * pin + 1])
        return cls(disc, mat, box, rep, pin, w_dofs, tol, porosity)

    @property
    def n_reduced_points(self) -> int:
        return int(self.rep.max()) + 1

    @property
    def area(self) -> float:
        """The periodic box's reference area (pores included): the average stress's."""
        return float(np.prod(self.box[1] - self.box[0]))

    @property
    def period(self) -> np.ndarray:
        return self.box[1] - self.box[0]

    def reference_points(self, params=None) -> jnp.ndarray:
        """The reference control points of a design (None: the scene's initial one; checked as
        Simulator.check_params checks it), its opposite edges checked to match to round-off where
        concrete."""
        init = self.disc.init_params()
        params = init if params is None else params
        params = checks.design(params, init, self.disc.design.bounds(), self.disc.spec.name)
        X = self.disc.reference_points(params)
        if not isinstance(X, jax.core.Tracer):  # traced: the topology's check stands
            self.check_matching(np.asarray(X))
        return X

    def check_matching(self, X: np.ndarray) -> float:
        """The largest distance between a control point shifted onto its tied partner and that
        partner (0 to round-off for a periodic design); ConfigError beyond the tolerance."""
        X = np.asarray(X, float)
        gap = self.mismatch(X)
        if gap > self.tol:
            raise ConfigError(
                f"scene {self.disc.spec.name}: the design breaks periodicity: tied control points "
                f"are {gap:.3g} off one period apart (corner moves on the box edges?)"
            )
        return gap

    def mismatch(self, X: np.ndarray) -> float:
        """max over tied pairs of |X_p - X_rep(p) - shift|, the shift a whole number of periods."""
        ref = X[self.representatives()]
        shift = np.round((X - ref) / self.period) * self.period
        return float(np.max(np.abs(X - ref - shift)))

    def representatives(self) -> np.ndarray:
        """(n_points,) for each control point, a control point of its reduced class (the first)."""
        first = np.full(self.n_reduced_points, len(self.rep))
        np.minimum.at(first, self.rep, np.arange(len(self.rep)))
        return first[self.rep]

    def pin_position(self, X) -> jnp.ndarray:
        """The origin of the affine field: the first control point of the pinned class (w = 0 on
        the whole class)."""
        return X[self.representatives()[np.flatnonzero(self.rep == self.pin)[0]]]

    def tied_pairs(self) -> np.ndarray:
        """(n, 2) control point pairs (p, q) tied across the box: q the first control point of p's
        class (X_p - X_q a whole number of periods, not zero)."""
        reps = self.representatives()
        p = np.flatnonzero(reps != np.arange(len(reps)))
        return np.stack([p, reps[p]], axis=1)
