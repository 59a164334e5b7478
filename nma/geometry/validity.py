"""Is a deformed state a physical object?  The checks a converged equilibrium must pass to be a
result.

The energy sees the material only at its Gauss points, so an equilibrium can be inverted between
them, and the model has no contact, so a pore's walls can pass through each other.  Two checks:

- **det F over the whole material.**  On a Bezier element of a quadratic B-spline map, det(dx/dxi)
  is a polynomial of bidegree (3, 3), so its 4 x 4 Bernstein coefficients (from its values at 4 x 4
  points of the element, corners included) bound it from below, and det F = det(dx/dxi) /
  det(dX/dxi) has its sign.  An element whose coefficients are not all positive while its sampled
  values are is split in halves (exactly, by the subdivision matrices) up to SUBDIVISIONS times; one
  whose sign is still open after that is counted as undecided.  `min_J` is the smallest det F at the
  points evaluated (the 4 x 4 of each element and those of its subdivisions): the resolution is
  stated with it.
- **The boundary curves** (the outer boundary and every pore, exactly the patches' free edges,
  through `per_span` points per knot span): a curve that crosses itself, two curves that cross or
  touch (pore through pore, pore through the outer boundary), a pore turned inside out (its enclosed
  area changed sign), and the smallest gap between two distinct curves.  The polylines' chords are
  within h^2 |x''| / (8 per_span^2) of the curves (h: a span's parameter length), far below a wall's
  width at the default per_span.

Reported beside the checks, not part of them: the boundary's smallest stretch along itself (a
chord's deformed over its reference length).  A compressed wall is still an object, but an
incompressible neo-Hookean solid's surface under plane-strain compression creases (folds onto
itself) below a stretch of 0.65 (Hong, Zhao & Suo 2009, Appl. Phys. Lett. 95, 111901), which a model
that leaves out a wall's contact with itself near itself cannot do: there a nearly incompressible
material may not do what the model says.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from functools import cached_property, lru_cache

import numpy as np

from .bspline import CHECK_POINTS, basis_matrix, span_points
from .mesh import Mesh
from .outline import enclosed_area, oriented_loops, sample_loop

PER_SPAN = 8  # polyline points per knot span of a boundary edge
SUBDIVISIONS = 3  # halvings of an element whose Bernstein bound leaves the sign of det F open
_CUBIC = 3  # det(dx/dxi) of a quadratic map: bidegree (3, 3)
_NODES = CHECK_POINTS  # 4 per span and direction, ends included: the barrier's check points too


def _bernstein(t: np.ndarray) -> np.ndarray:
    """(n, 4) cubic Bernstein polynomials at t in [0, 1]."""
    from math import comb

    t = np.asarray(t, float)[:, None]
    k = np.arange(_CUBIC + 1)[None]
    return np.asarray([comb(_CUBIC, int(i)) for i in k[0]])[None] * t**k * (1 - t) ** (_CUBIC - k)


_TO_BERNSTEIN = np.linalg.inv(_bernstein(_NODES))  # values at _NODES -> Bernstein coefficients


@lru_cache(maxsize=None)
def _halves() -> tuple[np.ndarray, np.ndarray]:
    """Subdivision matrices: the Bernstein coefficients on [0, 1/2] and [1/2, 1] from those on [0,
    1]."""
    return tuple(_TO_BERNSTEIN @ _bernstein(a + 0.5 * _NODES) for a in (0.0, 0.5))


@lru_cache(maxsize=None)
def _element_bases(m: int, grading: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Basis (S*4, m) and derivative at the 4 equally spaced points (ends included) of every knot
    span."""
    t = span_points(m, _NODES, grading).ravel()
    # the right end of a span is the left limit there: inside a patch the basis is C1, so either
    # side
    t = np.minimum(t, 1.0 - 1e-12)
    return basis_matrix(t, m, grading=grading), basis_matrix(t, m, 1, grading)


def _element_centres(mesh: Mesh, points: np.ndarray) -> np.ndarray:
    """(P * S * S, 2) the centre (parametric midpoint) of every Bezier element, in patch order."""
    m, g = mesh.fidelity.ctrl_per_patch, mesh.fidelity.grading
    B = basis_matrix(np.minimum(span_points(m, [0.5], g).ravel(), 1.0 - 1e-12), m, grading=g)
    nets = points[mesh.patch_points].reshape(mesh.n_patches, m, m, 2)
    return np.einsum("ai,bj,pijd->pabd", B, B, nets, optimize=True).reshape(-1, 2)


def _jacobian_dets(mesh: Mesh, points: np.ndarray) -> np.ndarray:
    """det(dx/dxi) at the 4 x 4 points of every Bezier element: (..., P, S, S, 4, 4)."""
    m = mesh.fidelity.ctrl_per_patch
    B, dB = _element_bases(m, mesh.fidelity.grading)
    nets = points[..., mesh.patch_points, :].reshape(*points.shape[:-2], mesh.n_patches, m, m, 2)
    # contracted one basis at a time (optimize): m times fewer operations than all at once
    dxi = np.einsum("ai,bj,...pijd->...pabd", dB, B, nets, optimize=True)
    deta = np.einsum("ai,bj,...pijd->...pabd", B, dB, nets, optimize=True)
    det = dxi[..., 0] * deta[..., 1] - dxi[..., 1] * deta[..., 0]  # (..., P, 4S, 4S)
    S = m - 2
    return det.reshape(*det.shape[:-2], S, 4, S, 4).swapaxes(-3, -2)


@dataclass(frozen=True)
class Validity:
    """What the checks found in one state; `valid` only if nothing."""

    valid: bool
    min_J: float  # smallest det F at the points evaluated
    min_J_at: list  # where: the reference position of its element's centre
    inverted_elements: int  # Bezier elements where det F <= 0 somewhere (certain)
    undecided_elements: int  # elements whose sign the bound left open after subdivision
    self_crossing: list = field(default_factory=list)  # curves that cross themselves
    crossing: list = field(default_factory=list)  # pairs of curves that cross or touch
    inside_out: list = field(default_factory=list)  # pores whose enclosed area changed sign
    min_gap: float = float("inf")  # smallest distance between two distinct boundary curves
    min_gap_between: list = field(default_factory=list)
    # smallest stretch of a boundary curve along itself (not a check)
    min_boundary_stretch: float = 1.0
    # where: the chord's reference midpoint
    min_boundary_stretch_at: list = field(default_factory=list)

    def problems(self) -> list[str]:
        """What is wrong, in words (empty for a valid state)."""
        out = []
        if self.inverted_elements:
            out.append(
                f"material inverted (det F down to {self.min_J:.3g} near ({self.min_J_at[0]:.3g}, "
                f"{self.min_J_at[1]:.3g})) in {self.inverted_elements} elements"
            )
        out += [f"{c} crosses itself" for c in self.self_crossing]
        out += [f"{a} and {b} cross" for a, b in self.crossing]
        out += [f"{c} turned inside out" for c in self.inside_out]
        return out

    def record(self) -> dict:
        return {**asdict(self), "problems": self.problems()}


class StateChecker:
    """The checks of one discretisation, with what depends on the reference only computed once."""

    def __init__(self, mesh: Mesh, X, per_span: int = PER_SPAN):
        self.mesh, self.per_span = mesh, per_span
        self.X = np.asarray(X, float)
        self.loops = oriented_loops(mesh, self.X)
        reference = self._polylines(self.X)
        pores = reference[1:]
        self.names = ["outer boundary"] + [
            "pore at ({:.3g}, {:.3g})".format(*line.mean(axis=0)) for line in pores
        ]
        self.area_signs = np.sign(self._areas(self.X))
        closed = [np.concatenate([p, p[:1]]) for p in reference]
        self.ref_chords = np.concatenate(
            [np.linalg.norm(np.diff(p, axis=0), axis=1) for p in closed]
        )
        self.ref_midpoints = np.concatenate([0.5 * (p[1:] + p[:-1]) for p in closed])
        self.ref_dets = _jacobian_dets(mesh, self.X)  # > 0 wherever the reference is a valid map
        self.centres = _element_centres(mesh, self.X)
        # gaps are looked for between curves whose boxes are this close: half a pore's size, so that
        # a pore's neighbours across a wall (and diagonally) are always among them
        self.margin = (
            0.5 * float(np.median([np.ptp(p, axis=0).max() for p in pores])) if pores else 0.0
        )

    def _polylines(self, x: np.ndarray) -> list[np.ndarray]:
        return [
            sample_loop(x[loop], self.per_span, self.mesh.fidelity.grading) for loop in self.loops
        ]

    def _areas(self, x: np.ndarray) -> np.ndarray:
        """Enclosed areas (..., loops) of states x (..., n_points, 2)."""
        return np.stack(
            [enclosed_area(x[..., loop, :], self.mesh.fidelity.grading) for loop in self.loops],
            axis=-1,
        )

    @cached_property
    def resolution(self) -> str:
        return (
            f"det F at 4 x 4 points per Bezier element and Bernstein bounds, up to {SUBDIVISIONS} "
            f"subdivisions; boundary curves through {self.per_span} points per knot span"
        )

    def check(self, u) -> Validity:
        """The checks of one state, displacement u (n_points, 2)."""
        return self.check_batch(np.asarray(u, float)[None])[0]

    def check_batch(self, us, ok=None) -> list[Validity | None]:
        """The checks of states us (n, n_points, 2); None for a state not to check (ok[i] False: a
        solve that failed)."""
        us = np.asarray(us, float).reshape(-1, *self.X.shape)
        ok = np.ones(len(us), bool) if ok is None else np.asarray(ok, bool)
        x = self.X[None] + us[ok]
        out: list[Validity | None] = [None] * len(us)
        if not len(x):
            return out
        min_J, where, inverted, undecided = self._det_f(x)
        curves = self._curves(x)
        for k, i in enumerate(np.flatnonzero(ok)):
            c = {key: v[k] for key, v in curves.items()}
            valid = not (inverted[k] or c["self_crossing"] or c["crossing"] or c["inside_out"])
            out[i] = Validity(
                valid=bool(valid),
                min_J=float(min_J[k]),
                min_J_at=self.centres[where[k]].tolist(),
                inverted_elements=int(inverted[k]),
                undecided_elements=int(undecided[k]),
                **c,
            )
        return out

    def _det_f(self, x: np.ndarray):
        """Per state: the smallest det F at the points evaluated, the elements inverted somewhere
        (certain), and those whose sign the bound left open."""
        n = len(x)
        values = _jacobian_dets(self.mesh, x).reshape(n, -1, 4, 4)  # one 4 x 4 table per element
        E = values.shape[1]
        ref = np.broadcast_to(self.ref_dets.reshape(1, E, 4, 4), values.shape).reshape(-1, 4, 4)
        values = values.reshape(-1, 4, 4)
        # J where the reference is a map
        ratio = lambda a, b: a / np.where(b > 0, b, np.nan)
        # the smallest det F of each element so far (its 4 x 4 points, then its subdivisions'
        # corners)
        element_J = np.nanmin(ratio(values, ref).reshape(n * E, 16), axis=1)
        bad = np.any(values <= 0, axis=(1, 2))
        bern = lambda v: _TO_BERNSTEIN @ v @ _TO_BERNSTEIN.T
        coeffs = bern(values)
        owner = np.flatnonzero(~bad & (coeffs.min(axis=(1, 2)) <= 0))
        pieces, ref_pieces = coeffs[owner], bern(ref[owner])
        lo, hi = _halves()
        # a piece's corner coefficients are values there
        corner = np.s_[:, [0, 0, -1, -1], [0, -1, 0, -1]]
        for _ in range(SUBDIVISIONS):
            if not len(pieces):
                break
            split = lambda c: np.concatenate([a @ c @ b.T for a in (lo, hi) for b in (lo, hi)])
            pieces, ref_pieces, owner = split(pieces), split(ref_pieces), np.tile(owner, 4)
            np.fmin.at(
                element_J, owner, np.nanmin(ratio(pieces[corner], ref_pieces[corner]), axis=1)
            )
            certain = np.any(pieces[corner] <= 0, axis=1)
            bad[owner[certain]] = True
            still = ~certain & (pieces.min(axis=(1, 2)) <= 0) & ~bad[owner]
            pieces, ref_pieces, owner = pieces[still], ref_pieces[still], owner[still]
        open_ = np.zeros_like(bad)
        open_[owner] = True
        per_state = lambda flags: flags.reshape(n, -1).sum(axis=1)
        element_J = element_J.reshape(n, E)
        worst = np.argmin(np.where(np.isnan(element_J), np.inf, element_J), axis=1)
        return element_J[np.arange(n), worst], worst, per_state(bad), per_state(open_ & ~bad)

    def _curves(self, x: np.ndarray) -> dict:
        """Per state: the curves that cross themselves, the pairs that cross or touch, the pores
        turned inside out, the smallest gap between two distinct curves and which."""
        import shapely

        n, R = len(x), len(self.loops)
        lines = [
            sample_loop(x[:, loop], self.per_span, self.mesh.fidelity.grading)
            for loop in self.loops
        ]
        lines = [np.concatenate([p, p[:, :1]], axis=1) for p in lines]  # closed
        sizes = np.array([p.shape[1] for p in lines])
        coords = np.concatenate(lines, axis=1).reshape(-1, 2)  # state-major, then loop
        rings = shapely.linestrings(coords, indices=np.repeat(np.arange(n * R), np.tile(sizes, n)))
        rings = rings.reshape(n, R)
        simple = shapely.is_simple(rings)
        # pairs of curves to test: boxes closer than the margin (boxes further apart cannot cross,
        # and their gap is at least the margin)
        # (n, R, 2, 2)
        boxes = np.stack([np.stack([p.min(axis=1), p.max(axis=1)], axis=1) for p in lines], axis=1)
        apart = np.maximum(
            boxes[:, :, None, 0] - boxes[:, None, :, 1], boxes[:, None, :, 0] - boxes[:, :, None, 1]
        )
        near = (apart.max(axis=-1) <= self.margin) & np.triu(np.ones((R, R), bool), 1)[None]
        s, a, b = np.nonzero(near)
        dist = shapely.distance(rings[s, a], rings[s, b])
        signs = np.sign(self._areas(x))
        chords = np.concatenate(
            [np.linalg.norm(np.diff(p, axis=1), axis=-1) for p in lines], axis=1
        )
        stretch = chords / self.ref_chords
        shortest = np.argmin(stretch, axis=1)
        out = {
            "self_crossing": [],
            "crossing": [],
            "inside_out": [],
            "min_gap": [],
            "min_gap_between": [],
            "min_boundary_stretch": stretch[np.arange(n), shortest].tolist(),
            "min_boundary_stretch_at": self.ref_midpoints[shortest].tolist(),
        }
        for k in range(n):
            mine = s == k
            d, pa, pb = dist[mine], a[mine], b[mine]
            out["self_crossing"].append([self.names[r] for r in np.flatnonzero(~simple[k])])
            out["crossing"].append(
                [[self.names[i], self.names[j]] for i, j in zip(pa[d <= 0], pb[d <= 0])]
            )
            out["inside_out"].append(
                [self.names[r] for r in np.flatnonzero(signs[k] != self.area_signs) if r > 0]
            )
            best = int(np.argmin(d)) if len(d) else None
            out["min_gap"].append(float(d[best]) if best is not None else float("inf"))
            out["min_gap_between"].append(
                [] if best is None else [self.names[pa[best]], self.names[pb[best]]]
            )
        return out


def summarise(records: list[Validity | None]) -> dict:
    """The numbers metrics.json and the logs carry for a set of states (None: a solve that failed):
    how many were checked and not valid, the smallest det F, the smallest gap and the boundary's
    smallest stretch along itself (None if unknown)."""
    done = [r for r in records if r is not None]
    finite = lambda values: min((v for v in values if np.isfinite(v)), default=None)
    return {
        "invalid_states": sum(not r.valid for r in done),
        "checked_states": len(done),
        "min_J": finite(r.min_J for r in done),
        "min_gap": finite(r.min_gap for r in done),
        "min_boundary_stretch": finite(r.min_boundary_stretch for r in done),
    }


def describe(summary: dict, invalid: dict, contact: bool = False, limit: int = 3) -> str:
    """A warning's words for the invalid states of an evaluation: how many, and the first few
    problems."""
    first = "; ".join(f"sample {i}: {', '.join(p)}" for i, p in list(invalid.items())[:limit])
    why = (
        "its energy sees det F only at Gauss points, and contact leaves out a wall folding within "
        "3 contact distances of itself"
        if contact
        else "the model has no contact (contact=on), and its energy sees det F only at Gauss points"
    )
    return (
        f"{summary['invalid_states']} of {summary['checked_states']} evaluated states are not "
        "physical "
        f"objects ({why}): {first}" + ("; ..." if len(invalid) > limit else "")
    )
