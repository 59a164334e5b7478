"""The solid whose energy nma.mechanics.energy integrates: the mesh, the material and, where the
pores' walls may touch, their contact model."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.mesh import Mesh
from .contact import ContactModel
from .material import Material


@dataclass(frozen=True, eq=False)
class Solid:
    mesh: Mesh
    material: Material = Material()
    contact: ContactModel | None = None  # None: the pores' walls may pass through each other

    @property
    def block_points(self) -> np.ndarray:
        """(E + Ec, 9) the points of every tangent block: the Bezier elements, then the contact
        blocks."""
        blocks = self.mesh.elem_points.reshape(-1, 9)
        return np.concatenate([blocks, self.contact.block_points]) if self.contact else blocks
