"""Physical units of a run: the scene's lengths in millimetres and its forces in newtons.

A scene is drawn in length units (a paper cell is 5) and its material's stresses are in the unit of
its parameters.  The model is plane strain without a thickness factor, so a force it computes (a
reaction, the force an actuator pushes with) is per unit thickness, in stress x length.  With the
part's scale (`part.scale`, mm per length unit), its thickness (`part.thickness`, mm) and the
stresses' unit (`material.unit`), a force in newtons is  F [N] = F x (MPa per stress unit) x scale
[mm] x thickness [mm].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .mechanics.options import MPA_PER_UNIT


@dataclass(frozen=True)
class Units:
    """How a run's lengths and forces convert to mm and N; None where the run does not say."""

    mm_per_unit: float | None = None  # part.scale
    newton_per_force: float | None = None  # part.scale x part.thickness x MPa per material.unit
    thickness_mm: float | None = None
    stress_unit: str | None = None

    @classmethod
    def of(cls, part, material) -> "Units":
        """From a run's `part` and `material` settings."""
        force = None
        if part.scale is not None and part.thickness is not None and material.unit is not None:
            force = MPA_PER_UNIT[material.unit] * part.scale * part.thickness
        return cls(part.scale, force, part.thickness, material.unit)

    @property
    def length_name(self) -> str:
        return "mm" if self.mm_per_unit is not None else "length units"

    @property
    def force_name(self) -> str:
        if self.newton_per_force is not None:
            return "N"
        return f"{self.stress_unit or 'stress unit'} x length unit, per unit thickness"

    def record(self) -> dict:
        """What a result says of its units (metrics.json, nma.simulate's JSON, the export's
        report)."""
        return {
            "length": self.length_name,
            "mm_per_unit": self.mm_per_unit,
            "force": self.force_name,
            "newton_per_force_unit": self.newton_per_force,
            "thickness_mm": self.thickness_mm,
            "stress": self.stress_unit,
        }

    def convert(self, value, dimension: str | None):
        """`value` (a number or an array) of `dimension` ('length', 'force', or None: no unit to
        convert) in mm or N where the run says how, else as it is."""
        factor = {"length": self.mm_per_unit, "force": self.newton_per_force}.get(dimension or "")
        if factor is None:
            return None
        return (np.asarray(value, dtype=float) * factor).tolist()

    def physical(self, name: str, value, dimension: str | None) -> dict:
        """{name_mm or name_N: value converted} where it converts, else {}."""
        converted = self.convert(value, dimension)
        if converted is None:
            return {}
        return {f"{name}_{'mm' if dimension == 'length' else 'N'}": converted}


def run_record(units: Units, sim, mat, task, evaluation) -> dict:
    """metrics.json's physical part: the units, the metric in mm or N where it is a length or a
    force, and the largest force each actuation pushes with over the evaluation's converged
    states."""
    import jax

    record = {
        "units": units.record(),
        **units.physical(
            task.metric_name, evaluation.record[task.metric_name], task.metric_dimension
        ),
    }
    if evaluation.u is None or not np.any(evaluation.ok) or sim.n_actuations == 0:
        return record
    u = np.asarray(evaluation.u)[np.asarray(evaluation.ok)]
    forces = np.asarray(jax.lax.map(lambda ui: sim.actuation_forces(evaluation.X, ui, mat), u))
    largest = np.max(np.abs(forces), axis=0).tolist()
    return {
        **record,
        "max_actuation_force": largest,
        **units.physical("max_actuation_force", largest, "force"),
        "stretch_range": stretch_range(sim, evaluation.X, u),
    }


def stretch_range(sim, X, u) -> list[float]:
    """[smallest, largest] in-plane principal stretch at the Gauss points of the states u (n,
    n_points, 2): the range the material's law must hold over (material.stretches is where it was
    checked)."""
    import jax

    from .mechanics.energy import deformation_gradient, quadrature
    from .mechanics.laws import principal_stretch_range

    quad = quadrature(sim.disc.solid, X)
    lo, hi = jax.lax.map(
        lambda ui: principal_stretch_range(deformation_gradient(sim.disc.mesh, quad, ui)), u
    )
    return [float(np.min(lo)), float(np.max(hi))]
