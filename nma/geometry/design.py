"""The differentiable design map: geometry parameters -> design control nets (P, 5, 5, 2).

Parameters are a dict of arrays, holding only what the scene models:

- `radii` (n_porous_cells, 16): pore radii, 4 per side, the corner radius shared by neighbouring
  sides (12, 3 per side, with round pore corners: each corner's is derived);
- `corners` (n_movable_nodes, 2): offsets of the interior grid nodes, inside +-corner_box;
- `pore_radii` (4 M,): radii of the central pore on its M-gon of ring nodes (3 M: round);
- `colours` (P, 5, 5): colour net per patch (logits; the field is sigmoid of the spline).

Patch order: porous cells (4 patches each, sides bottom, right, top, left), central pore, solid
cells.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from .bspline import DESIGN_CTRL
from .scene import POROUS, SOLID, PatchSceneSpec, SceneSpec

_T = np.linspace(0.0, 1.0, DESIGN_CTRL)  # design net parameters along a side / radially
# smallest corner turn of a cell, relative to the square grid's, that projection allows
MIN_TURN = 0.05


def radii_per_side(round_corners: bool) -> int:
    """Design radii per pore side: the corner's and the side's 3 inner ones; the 3 alone where the
    corners are round (each corner's radius then follows from its neighbours, see pore_nets)."""
    return DESIGN_CTRL - 2 if round_corners else DESIGN_CTRL - 1


def _round_corner_radii(centroid, outer, inner_sides) -> jnp.ndarray:
    """(M,) the radius that puts each pore corner on the line between its neighbouring control
    points (side i-1's last inner one, side i's first), so the walls meet tangent there (G1) instead
    of at an angle: the corner point centroid + r (node - centroid) on that line."""
    cross = lambda a, b: a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    before, after = jnp.roll(inner_sides[:, -1], 1, axis=0), inner_sides[:, 0]
    chord, ray = after - before, outer[:, 0] - centroid
    return cross(chord, before - centroid) / cross(chord, ray)


def pore_nets(polygon: jnp.ndarray, radii: jnp.ndarray, round_corners: bool = False) -> jnp.ndarray:
    """Nets (M, 5, 5, 2) of the M patches around a pore on a polygon of M nodes (counter-clockwise).

    Side i's outer edge runs straight from node i to node i+1; its inner edge is
    centroid + r * (outer - centroid); rows between are linear.  Index [side, along, radial]:
    radial row 0 is the outer edge, so (along, radial) is positively oriented.  The corner radius
    (shared by neighbouring sides) is a design radius, where the walls meet at an angle (a
    re-entrant corner of the material, whose stress is singular), or with `round_corners` derived so
    they meet tangent (_round_corner_radii): `radii` then holds the sides' inner radii alone."""
    m = polygon.shape[0]
    nxt = jnp.roll(polygon, -1, axis=0)
    outer = polygon[:, None, :] + _T[None, :, None] * (nxt - polygon)[:, None, :]  # (M, 5, 2)
    centroid = polygon.mean(axis=0)
    r = radii.reshape(m, radii_per_side(round_corners))
    if round_corners:
        sides = centroid + r[..., None] * (outer[:, 1:-1] - centroid)
        r = jnp.concatenate([_round_corner_radii(centroid, outer, sides)[:, None], r], axis=1)
    # (M, 5): shared corner radius
    r_side = jnp.concatenate([r, jnp.roll(r[:, :1], -1, axis=0)], axis=1)
    inner = centroid + r_side[..., None] * (outer - centroid)
    return outer[:, :, None, :] + _T[None, None, :, None] * (inner - outer)[:, :, None, :]


def _bilinear(quad: jnp.ndarray) -> jnp.ndarray:
    s = jnp.asarray(_T)
    S, T = jnp.meshgrid(s, s, indexing="ij")
    w = jnp.stack([(1 - S) * (1 - T), S * (1 - T), S * T, (1 - S) * T], axis=-1)  # (5, 5, 4)
    return jnp.einsum("ijc,cd->ijd", w, quad)


@dataclass(frozen=True, eq=False)
class GridDesign:
    """Static description of a cell-grid design; `nets(params)` is the differentiable map."""

    spec: SceneSpec
    nodes: np.ndarray  # (N, 2) initial grid nodes, index i + (nx + 1) * j
    movable: np.ndarray  # (n_movable,) node indices that corner offsets move
    porous: np.ndarray  # (n_porous, 4) node indices, counter-clockwise from bottom-left
    solid: np.ndarray  # (n_solid, 4)
    central: np.ndarray  # (M,) ring node indices of the central pore (may be empty)

    @classmethod
    def from_spec(cls, spec: SceneSpec) -> "GridDesign":
        nx, ny = spec.shape
        X, Y = np.meshgrid(spec.x_breaks, spec.y_breaks, indexing="xy")
        nodes = np.stack([X.ravel(), Y.ravel()], axis=1)
        nid = lambda i, j: i + (nx + 1) * j
        cell_nodes = lambda i, j: [nid(i, j), nid(i + 1, j), nid(i + 1, j + 1), nid(i, j + 1)]
        porous = [
            cell_nodes(i, j) for j in range(ny) for i in range(nx) if spec.token(i, j) == POROUS
        ]
        solid = [
            cell_nodes(i, j) for j in range(ny) for i in range(nx) if spec.token(i, j) == SOLID
        ]
        central = [nid(i, j) for i, j in spec.central_pore]
        used = set(np.ravel(porous).tolist()) | set(np.ravel(solid).tolist()) | set(central)
        movable = []
        if spec.corner_box > 0:
            locked = {nid(i, j) for i, j in spec.locked_nodes}
            # nodes of solid cells stay put too, so every cell keeps its bilinear/conforming shape
            locked |= set(np.ravel(solid).tolist())
            movable = [
                nid(i, j)
                for j in range(1, ny)
                for i in range(1, nx)
                if nid(i, j) in used and nid(i, j) not in locked
            ]
        as_int = lambda a, w: np.asarray(a, dtype=np.int64).reshape(-1, w)
        return cls(
            spec,
            nodes,
            np.asarray(movable, dtype=np.int64),
            as_int(porous, 4),
            as_int(solid, 4),
            np.asarray(central, dtype=np.int64),
        )

    @property
    def n_patches(self) -> int:
        return 4 * len(self.porous) + len(self.central) + len(self.solid)

    def init_params(self) -> dict[str, jnp.ndarray]:
        s = self.spec
        per_side = radii_per_side(s.round_pore_corners)
        p = {"radii": jnp.full((len(self.porous), 4 * per_side), s.radii_init)}
        if len(self.movable):
            p["corners"] = jnp.zeros((len(self.movable), 2))
        if len(self.central):
            p["pore_radii"] = jnp.full((len(self.central) * per_side,), s.central_radii_init)
        if s.colours:
            p["colours"] = jnp.zeros((self.n_patches, DESIGN_CTRL, DESIGN_CTRL))
        return p

    def topology_params(self) -> dict[str, jnp.ndarray]:
        """Parameters at which every cell is a regular pore: the reference for merging points."""
        p = self.init_params()
        return {
            **p,
            **{k: jnp.full_like(p[k], 0.5) for k in ("radii", "pore_radii") if k in p},
            **({"corners": jnp.zeros_like(p["corners"])} if "corners" in p else {}),
        }

    def bounds(self) -> dict[str, tuple[float, float]]:
        """Box of every geometry parameter (projection target after each optimiser update)."""
        lo, hi = self.spec.radii_bounds
        b = {
            "radii": (lo, hi),
            "corners": (-self.spec.corner_box, self.spec.corner_box),
            "pore_radii": (lo, hi),
            "colours": (-np.inf, np.inf),
        }
        return {k: b[k] for k in self.init_params()}

    def random_params(
        self, rng: np.random.Generator, spread: float = 0.6
    ) -> dict[str, jnp.ndarray]:
        """A random non-uniform design inside the box (studies measure on it, not on the symmetric
        initial design, whose gradients vanish in symmetric directions): radii and corner moves
        uniform over the central `spread` of their ranges, corners then kept convex, colours
        standard normal."""
        init, bounds = self.init_params(), self.bounds()
        out = {}
        for k, v in init.items():
            lo, hi = bounds[k]
            if k == "colours":
                out[k] = jnp.asarray(rng.standard_normal(v.shape))
            else:
                mid, half = 0.5 * (lo + hi), 0.5 * spread * (hi - lo)
                out[k] = jnp.asarray(rng.uniform(mid - half, mid + half, v.shape))
        # a valid previous design
        at_rest = {**out, "corners": init["corners"]} if "corners" in init else out
        return self.project(out, at_rest)

    def corner_turns(self, params) -> jnp.ndarray:
        """Turn (cross product of consecutive edges) at every corner of every cell, and for the
        central pore's polygon the area of each sector (centroid, node i, node i+1), relative to
        their values in the undeformed grid: all > 0 means every cell is convex and the central
        polygon star-shaped about its centroid, so each pore's sides see the centroid its patches
        are built towards and the patches cannot fold.  (The central polygon has straight corners,
        where a turn is 0 at rest: its sectors are the measure that is positive there.)"""
        cross = lambda a, b: a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]

        def turns(nodes):
            q = nodes[self.porous]
            e = jnp.roll(q, -1, axis=1) - q
            out = [cross(e, jnp.roll(e, -1, axis=1)).ravel()]
            if len(self.central):
                r = nodes[self.central] - jnp.mean(nodes[self.central], axis=0)
                out.append(cross(r, jnp.roll(r, -1, axis=0)))
            return jnp.concatenate(out)

        return turns(self.node_positions(params)) / turns(jnp.asarray(self.nodes))

    def pore_corner_angles(self, params) -> np.ndarray:
        """(n_porous, 4) the angle inside each cell's pore, in degrees (0 to 360), at the corner
        where side s's wall begins: the point that corner radius radii[:, 4 s] places.  The walls of
        neighbouring sides meet there with only C0 continuity, so the material around the corner
        spans 360 deg minus this angle: below 180 a re-entrant corner, whose stress is singular like
        r^(lambda - 1), lambda from 0.5 (a sharp pore corner: a crack) to 1 (a straight wall)
        (Williams 1952, J. Appl. Mech. 19, 526); above 180 the wall dents into the pore.  Round pore
        corners (scene.round_pore_corners) are 180 everywhere: the walls meet tangent."""
        k = DESIGN_CTRL - 1
        walls = np.asarray(self.nets(params))[: 4 * len(self.porous), :, k].reshape(
            -1, 4, DESIGN_CTRL, 2
        )
        # side s's wall leaving the corner
        along = walls[:, :, 1] - walls[:, :, 0]
        # side s-1's wall back from it
        back = np.roll(walls, 1, axis=1)[:, :, k - 1] - walls[:, :, 0]
        # the walls run counter-clockwise around the pore: its inside is the turn from `along` to
        # `back`
        cross = along[..., 0] * back[..., 1] - along[..., 1] * back[..., 0]
        return np.degrees(np.arctan2(cross, np.sum(along * back, axis=-1))) % 360.0

    def project(self, params, previous) -> dict[str, jnp.ndarray]:
        """Clip every parameter into its box; if moved corners would make a cell (nearly)
        non-convex, go only the largest fraction of the step from `previous` (a valid design) that
        keeps every turn >= MIN_TURN.  A box below a quarter cell keeps cells convex by itself; the
        paper's 0.45-cell box does not, and relies on this."""
        clipped = {k: jnp.clip(v, *self.bounds()[k]) for k, v in params.items()}
        if "corners" not in clipped:
            return clipped
        step = clipped["corners"] - previous["corners"]
        ok = lambda t: (
            jnp.min(self.corner_turns({**clipped, "corners": previous["corners"] + t * step}))
            >= MIN_TURN
        )

        def bisect(_, lo_hi):
            lo, hi = lo_hi
            mid = 0.5 * (lo + hi)
            good = ok(mid)
            return jnp.where(good, mid, lo), jnp.where(good, hi, mid)

        t = jax.lax.cond(
            ok(1.0), lambda: 1.0, lambda: jax.lax.fori_loop(0, 30, bisect, (0.0, 1.0))[0]
        )
        return {**clipped, "corners": previous["corners"] + t * step}

    def node_positions(self, params) -> jnp.ndarray:
        nodes = jnp.asarray(self.nodes)
        if len(self.movable):
            nodes = nodes.at[self.movable].add(params["corners"])
        return nodes

    def nets(self, params) -> jnp.ndarray:
        nodes = self.node_positions(params)
        parts = []
        if len(self.porous):
            round_corners = self.spec.round_pore_corners
            cells = jax.vmap(lambda q, r: pore_nets(q, r, round_corners))(
                nodes[self.porous], params["radii"]
            )
            parts.append(cells.reshape(-1, DESIGN_CTRL, DESIGN_CTRL, 2))
        if len(self.central):
            parts.append(
                pore_nets(nodes[self.central], params["pore_radii"], self.spec.round_pore_corners)
            )
        if len(self.solid):
            parts.append(jax.vmap(_bilinear)(nodes[self.solid]))
        return jnp.concatenate(parts, axis=0)


@dataclass(frozen=True, eq=False)
class FixedDesign:
    """A geometry with no design parameters (a general multi-patch scene such as Cook's
    membrane)."""

    spec: PatchSceneSpec

    @property
    def n_patches(self) -> int:
        return self.spec.nets.shape[0]

    def init_params(self) -> dict[str, jnp.ndarray]:
        return {}

    def topology_params(self) -> dict[str, jnp.ndarray]:
        return {}

    def bounds(self) -> dict[str, tuple[float, float]]:
        return {}

    def random_params(self, rng, spread: float = 0.6) -> dict[str, jnp.ndarray]:
        return {}

    def project(self, params, previous) -> dict[str, jnp.ndarray]:
        return params

    def nets(self, params) -> jnp.ndarray:
        return jnp.asarray(self.spec.nets)


def make_design(spec) -> GridDesign | FixedDesign:
    return GridDesign.from_spec(spec) if isinstance(spec, SceneSpec) else FixedDesign(spec)
