"""Periodic scenes a metamaterials study starts from: the square array of circular holes (Mullin,
Deschanvres, Bertoldi & Boyce, PRL 99, 084301, 2007; Bertoldi, Reis, Willshaw & Mullin, Adv. Mater.
22, 361, 2010) as a k x m supercell, and a solid (pore-free) cell."""

from __future__ import annotations

import weakref

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError
from ..mechanics.energy import quadrature
from .cell import PeriodicCell

# along a side, the design net's inner control points (t = 1/4, 1/2, 3/4 of the side): their
# distance from the cell's centre over half the side
_SIDE = np.sqrt(1.0 + (2.0 * np.array([0.25, 0.5, 0.75]) - 1.0) ** 2)


def square_array(k: int = 1, m: int = 1, cell_size: float = 1.0, solid: bool = False) -> dict:
    """A periodic scene of k x m square cells (columns x rows): porous cells with round pore
    corners (the walls meet tangent), or solid cells (`solid`)."""
    for name, v in (("k", k), ("m", m)):
        if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 100:
            raise ConfigError(f"square_array: {name} must be an integer in [1, 100], got {v!r}")
    token = "S" if solid else "P"
    return {
        "name": f"square_array_{k}x{m}" + ("_solid" if solid else ""),
        "cells": "\n".join([token * k] * m),
        "cell_size": float(cell_size),
        "round_pore_corners": True,
        "radii_bounds": [0.1, 0.95],
        "radii_init": 0.5,
    }


def circle_params(cell: PeriodicCell, radius: float) -> dict:
    """The design whose pores' inner control points lie on circles of `radius` (a fraction of the
    cell's side) about each cell's centre, for a scene of square cells with round pore corners."""
    spec = cell.disc.spec
    if not spec.round_pore_corners:
        raise ConfigError(f"scene {spec.name}: circle_params needs round_pore_corners: true")
    params = cell.disc.init_params()
    side = np.tile(2.0 * radius / _SIDE, 4)
    lo, hi = spec.radii_bounds
    if side.min() < lo or side.max() > hi:
        raise ConfigError(
            f"scene {spec.name}: a circle of radius {radius:g} (of the cell) needs design radii "
            f"{side.min():.3g} to {side.max():.3g}, outside scene.radii_bounds [{lo}, {hi}]"
        )
    return {**params, "radii": jnp.broadcast_to(jnp.asarray(side), params["radii"].shape)}


# each discretisation's quadrature weights as a function of X, compiled once (a bisection for a
# porosity calls it tens of times)
_WEIGHTS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def porosity(cell: PeriodicCell, params) -> float:
    """The pores' share of the periodic box: 1 - the material's reference area / the box's."""
    X = cell.disc.reference_points(params)
    if cell.disc not in _WEIGHTS:
        solid = cell.disc.solid  # not the discretisation: the cache must not keep it alive
        _WEIGHTS[cell.disc] = jax.jit(lambda X: quadrature(solid, X).weights)
    area = float(jnp.sum(_WEIGHTS[cell.disc](X)))
    return 1.0 - area / cell.area


def circular_holes(cell: PeriodicCell, target: float = 0.5, iters: int = 30) -> tuple[dict, float]:
    """The circle_params design whose porosity is `target`, by bisection on the radius; returns
    (params, its porosity).  A target the scene's radii bounds cannot reach is refused, naming the
    porosities they allow."""
    if not 0.0 < target < 0.75:
        raise ConfigError(f"circular_holes: target porosity must be in (0, 0.75), got {target}")
    lo_b, hi_b = cell.disc.spec.radii_bounds
    smallest, largest = lo_b * _SIDE.max() / 2.0, hi_b * _SIDE.min() / 2.0
    lo, hi = smallest, largest
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        if porosity(cell, circle_params(cell, mid)) < target:
            lo = mid
        else:
            hi = mid
    params = circle_params(cell, 0.5 * (lo + hi))
    reached = porosity(cell, params)
    if abs(reached - target) > 1e-4:
        ends = [porosity(cell, circle_params(cell, r)) for r in (smallest, largest)]
        raise ConfigError(
            f"porosity {target:g} is out of reach of scene {cell.disc.spec.name}'s radii bounds "
            f"{[lo_b, hi_b]}: its circular holes have porosities from {min(ends):.4g} to "
            f"{max(ends):.4g}"
        )
    return params, reached
