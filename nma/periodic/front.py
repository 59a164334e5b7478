"""The periodic cell's front door: settings (plain mappings or preset names, checked as the
commands check them) turned into a PeriodicCell."""

from __future__ import annotations

import dataclasses
from typing import Any

from ..discretise import discretise
from ..resolve import contact_options, library_settings, material_of, material_params
from ..schema.compose import build
from ..schema.periodic import PeriodicSceneConfig
from ..schema.scene import SceneConfig
from .cell import PeriodicCell


def periodic_scene(scene: Any) -> PeriodicSceneConfig:
    """A checked PeriodicSceneConfig from a mapping or a SceneConfig (cells as one string or a list
    of rows), or a conf/scene preset's name (refused where it has supports or groups)."""
    from .. import config

    if isinstance(scene, PeriodicSceneConfig):
        return scene
    if isinstance(scene, str):
        scene = config.load("scene", scene)
    if isinstance(scene, SceneConfig):
        scene = dataclasses.asdict(scene)
    scene = dict(scene)
    if not isinstance(scene.get("cells", ""), str):
        scene["cells"] = "\n".join(scene["cells"])
    return build(PeriodicSceneConfig, scene)


def periodic_cell(
    scene: Any, fidelity=None, material=None, formulation: str = "auto", contact=None
) -> PeriodicCell:
    """A periodic cell of a scene (a mapping, a PeriodicSceneConfig, or a preset's name), at a
    fidelity (a mapping or preset's name; None: the scene's own) and a material (a mapping or
    preset's name; None: the paper's Neo-Hookean) and contact between the pores' walls (a mapping of
    the contact settings or a preset's name; None: none, `{"enabled": None}`: as the scene says),
    each checked as the commands check them, what is left to auto decided as
    Simulator.from_config decides it.

    Raises:
        ConfigError: A setting out of its range, a scene with supports, groups or more than one
            pinned point, or one whose opposite edges do not match (naming the point).
    """
    return cell_of(
        library_settings(periodic_scene(scene), fidelity, None, contact, formulation, material)
    )


def cell_of(s) -> PeriodicCell:
    """The periodic cell of resolved settings with a periodic `scene`, `fidelity`, `contact` and
    `material` (nma.resolve: library_settings, or nma.simulate's)."""
    disc = discretise(
        s.scene.spec(), s.fidelity, contact_options(s.contact), material_of(s.material)
    )
    return PeriodicCell.of(disc, material_params(s.material), getattr(s.scene, "porosity", None))
