"""The discretisation's own options, plain values (no config machinery; nma.schema.Fidelity declares their
ranges and presets)."""
from __future__ import annotations

from dataclasses import dataclass, fields


@dataclass(frozen=True)
class Resolution:
    """How finely a scene is discretised (nma.geometry.discretise)."""
    ctrl_per_patch: int = 5          # control points per patch side: 3k + 2, the design net refined
    quad_points: int = 5             # Gauss points per knot span and direction
    inversion_barrier: float = 0.0   # det F below which the barrier at the 4 x 4 check points acts; 0: off

    @classmethod
    def of(cls, setting=None) -> "Resolution":
        """From any setting that has these fields (a Fidelity); None: the paper's 5 x 5."""
        return cls() if setting is None else cls(*(getattr(setting, f.name) for f in fields(cls)))
