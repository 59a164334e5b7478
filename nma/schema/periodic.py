"""A periodic scene: a SceneConfig held by periodicity instead of supports (nma.periodic)."""

from __future__ import annotations

from dataclasses import dataclass

from .scene import SceneConfig


@dataclass
class PeriodicSceneConfig(SceneConfig):
    """A scene read as a periodic cell: SceneConfig's fields and checks, but held by periodicity
    instead of supports.  `pinned` is at most one point, where the fluctuation w is held at zero
    (rigid translation removed; none: the control point nearest the grid's bottom-left corner);
    `groups` and `supports` must be empty (F_bar is the load).  `contact` is the pores' own: every
    pore lies inside its cell, so its walls meet no wall across a periodic seam."""

    def _check_held(self):
        if self.groups:
            self.fail("groups", "must be empty in a periodic scene (F_bar is its load)")
        if self.supports:
            self.fail("supports", "must be empty in a periodic scene (periodicity holds it)")
        if len(self.pinned) > 1:
            self.fail(
                "pinned",
                "must be at most one point in a periodic scene (where w = 0 removes translation)",
                self.pinned,
            )
