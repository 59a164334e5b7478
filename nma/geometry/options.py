"""The discretisation's own options: plain values, each declared once with its range and meaning
(the config's `fidelity` group, nma.schema.Fidelity, takes them from here and adds its presets)."""

from __future__ import annotations

from dataclasses import dataclass, fields

from ..errors import ConfigError
from ..settings import bounded


GRADING_MAX = 4.0  # past it the outer thirds' largest span is over 4x the uniform one's


@dataclass(frozen=True)
class Resolution:
    """How finely a scene is discretised (nma.discretise)."""

    ctrl_per_patch: int = bounded(
        5,
        "[5, 1000]",
        doc="control points per patch side, 3k + 2: the 5 x 5 design net refined by knot insertion",
    )
    quad_points: int = bounded(
        5, "[2, 10]", doc="Gauss points per knot span and direction; 1 under-integrates"
    )
    inversion_barrier: float = bounded(
        0.0,
        "[0, 1)",
        doc="det F below which a barrier acts at 4 x 4 points of "
        "every element, corners included, where the Gauss points do not see, and "
        "Newton keeps det F > 0 there (nma.mechanics.energy); 0: off",
    )
    grading: float = bounded(
        1.0,
        f"[1, {GRADING_MAX:g}]",
        doc="knots graded towards every patch corner as "
        "(i/k)^grading in each side's outer thirds, where supports and actuated segments end "
        "(stress singularities; bspline.span_breaks); 1: uniform",
    )

    def __post_init__(self):
        if self.ctrl_per_patch is None or self.quad_points is None:  # fidelity=scene's open halves
            raise ValueError(
                "fidelity=scene leaves the discretisation to the scene: resolve it first "
                "(nma.fidelity.resolve)"
            )
        if self.ctrl_per_patch < 5 or (self.ctrl_per_patch - 2) % 3:
            raise ConfigError(
                f"fidelity.ctrl_per_patch must be 3k + 2 with k >= 1 (5, 8, 11, ...: one knot per "
                f"design span), got {self.ctrl_per_patch}"
            )
        if self.grading != 1.0 and self.ctrl_per_patch == 5:
            raise ConfigError(
                f"fidelity.grading={self.grading:g} changes nothing at 5 control points per patch "
                "(one span per design span); it needs fidelity.ctrl_per_patch >= 8, or leave it "
                "at 1"
            )
        if not 1.0 <= self.grading <= GRADING_MAX:
            raise ConfigError(
                f"fidelity.grading must be in [1, {GRADING_MAX:g}] (1: uniform knots), "
                f"got {self.grading}"
            )
        if self.quad_points < 1:
            raise ConfigError(f"fidelity.quad_points must be at least 1, got {self.quad_points}")

    @classmethod
    def of(cls, setting=None) -> "Resolution":
        """From a setting with these fields (a Fidelity); None: the paper's 5 x 5."""
        if setting is None or isinstance(setting, cls):
            return setting or cls()
        values = {f.name: getattr(setting, f.name) for f in fields(cls)}
        # auto, not resolved by a material: off, as for a compressible one
        if values["inversion_barrier"] is None:
            values["inversion_barrier"] = 0.0
        return cls(**values)
