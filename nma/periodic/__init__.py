"""Periodic metamaterials: a scene of k x m cells tied across its opposite edges, loaded by a
macroscopic deformation gradient F_bar with mixed control, its effective response along a load path
(average first Piola-Kirchhoff stress, lateral strain, Poisson's ratio), the bifurcations on it and
its gradients in the design (docs/how-to/periodic-metamaterials.md)."""

from ..schema.periodic import PeriodicSceneConfig
from .cell import COMPONENTS, PeriodicCell
from .front import periodic_cell, periodic_scene
from .gradients import path_gradient, response_gradient
from .designs import circle_params, circular_holes, porosity, square_array
from .load import MacroLoad, biaxial, load_of, shear, uniaxial
from .path import follow
from .problem import PeriodicProblem
from .solve import NewtonSettings, PathResult

__all__ = [
    "COMPONENTS",
    "MacroLoad",
    "NewtonSettings",
    "PathResult",
    "PeriodicCell",
    "PeriodicProblem",
    "PeriodicSceneConfig",
    "biaxial",
    "circle_params",
    "circular_holes",
    "follow",
    "load_of",
    "path_gradient",
    "periodic_cell",
    "periodic_scene",
    "porosity",
    "response_gradient",
    "shear",
    "square_array",
    "uniaxial",
]
