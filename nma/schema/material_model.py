"""What the auto settings choose for a material of a given compressibility (nma.resolve): its
formulation, Newton's corrector and limits, the inversion barrier and contact."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from ..mechanics.options import NEARLY_INCOMPRESSIBLE
from ..solver.options import NewtonOptions


@dataclass(frozen=True)
class MaterialModel:
    """What the auto settings choose for a material: its formulation, Newton's corrector and
    iteration limits, the inversion barrier and whether the pores' walls touch (None: as the scene
    says)."""

    formulation: str
    solver: dict
    inversion_barrier: float
    contact: Optional[bool]

    def contact_on(self, scene) -> bool:
        """contact=auto decided: by the material where it decides, else as the scene says."""
        return bool(scene.contact) if self.contact is None else self.contact


# A compressible material: the displacement model and Newton's defaults.  A nearly incompressible
# one (nu >= NEARLY_INCOMPRESSIBLE): the locking-free model with the settings under which every cell
# of the stability map at nu 0.499 converges (make study-incompressible;
# docs/how-to/nearly-incompressible.md).
_NEWTON = NewtonOptions()  # Newton's defaults: what auto chooses for a compressible material
COMPRESSIBLE = MaterialModel(
    "displacement",
    {
        "corrector": _NEWTON.corrector,
        "max_iters": _NEWTON.max_iters,
        "max_step_iters": _NEWTON.max_step_iters,
    },
    0.0,
    None,
)
NEARLY_INCOMPRESSIBLE_MODEL = MaterialModel(
    "mixed", {"corrector": "trust_region", "max_iters": 1000, "max_step_iters": 300}, 0.5, True
)


def material_model(nu: float) -> MaterialModel:
    """The model a material of Poisson's ratio nu needs: what material.formulation=auto,
    solver.corrector=auto, solver.max_iters, solver.max_step_iters and fidelity.inversion_barrier
    left unset, and contact=auto, take."""
    return NEARLY_INCOMPRESSIBLE_MODEL if nu >= NEARLY_INCOMPRESSIBLE else COMPRESSIBLE
