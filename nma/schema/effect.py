"""Settings that cannot do what they say, refused before any work: a value given for a setting
that the rest of the config leaves unused (a contact stiffness with contact off, a time step with
dynamics off), and a bound no design can meet (trainer.min_feature wider than any ligament the
scene can have).

A setting counts as given where it differs from its schema default: a default is never refused.
Each message is one line naming the setting and what would make it matter.  The commands call
these on the settings a user gave (nma.run and nma.export: from their validation, before they
fill anything in; nma.simulate and nma.fit: on construction of their configs); a trained run's
saved config is not checked again when nma.evaluate or nma.export reads it.
"""

from __future__ import annotations

import math
from dataclasses import MISSING, fields
from typing import Any, Iterator

from ..errors import ConfigError
from ..mechanics.options import ContactSettings

Unused = Iterator[tuple[str, Any, str]]  # (the setting's path, its value, why it has no effect)
_SCHEMES = "dynamics=newmark or dynamics=generalised_alpha"


def given(schema, name: str) -> bool:
    """Whether the field `name` of a schema instance differs from its declared default."""
    f = next(f for f in fields(schema) if f.name == name)
    default = (
        f.default
        if f.default is not MISSING
        else (f.default_factory() if f.default_factory is not MISSING else MISSING)
    )
    return default is MISSING or getattr(schema, name) != default


def _unused(schema, prefix: str, names, why: str) -> Unused:
    for name in names:
        if given(schema, name):
            yield f"{prefix}.{name}" if prefix else name, getattr(schema, name), why


def _contact_off(s) -> str | None:
    """Why contact is off for these settings (contact=auto decided as nma.resolve decides it, by
    the material's model), or None where it is on."""
    from .material_model import material_model

    if s.contact.enabled is None:
        if not material_model(s.material.nu).contact_on(s.scene):
            return f"contact is off (contact=auto, and scene {s.scene.name} leaves it off)"
        return None
    enabled = s.contact.enabled
    return None if enabled else "contact is off"


def _physics(s, command: str) -> Unused:
    """The groups nma.run and nma.simulate share: contact, dynamics, part."""
    off = _contact_off(s)
    if off:
        yield from _unused(
            s.contact,
            "contact",
            [f.name for f in fields(ContactSettings)],
            f"{off}; contact=on turns it on",
        )
    d = s.dynamics
    if not d.enabled:
        static = hasattr(s, "task") and not getattr(s.task, "in_time", False)
        why = (
            f"task {s.task.factory} is static, and dynamics is off; the tasks in time are in "
            "docs/reference/tasks.md"
            if static
            else f"dynamics is off (dynamics.scheme=off): choose {_SCHEMES}"
        )
        yield from _unused(d, "dynamics", [f.name for f in fields(d) if f.name != "scheme"], why)
    else:
        if d.scheme == "newmark":
            yield from _unused(
                d,
                "dynamics",
                ["rho_inf"],
                "it is generalised_alpha's spectral "
                "radius (newmark damps no frequency): choose "
                "dynamics=generalised_alpha",
            )
        if d.damping_ratio is None:
            yield from _unused(
                d,
                "dynamics",
                ["damping_frequency"],
                "it is where dynamics.damping_ratio holds: give dynamics.damping_ratio too",
            )
        if command == "nma.run":
            yield from _unused(
                d,
                "dynamics",
                ["ramp"],
                "it is nma.simulate's rise time; a task in time rises over task.ramp_steps",
            )
    if s.part.scale is None:
        yield from _unused(
            s.part,
            "part",
            ["thickness"],
            "forces stay per unit thickness "
            "without part.scale, the millimetres per length unit of the scene: give "
            "part.scale too",
        )


def _training(s) -> Unused:
    t = s.trainer
    if t.min_feature is None:
        yield from _unused(
            t,
            "trainer",
            ["feature_penalty"],
            "it weighs the trainer.min_feature bound: give trainer.min_feature (mm) too",
        )
    if t.inversion_penalty == 0:
        yield from _unused(
            t,
            "trainer",
            ["inversion_margin"],
            "it is where the inversion penalty "
            "acts, and trainer.inversion_penalty=0 turns that off",
        )
    if t.fields == "none":
        yield from _unused(
            t,
            "trainer",
            ["fields_samples"],
            "trainer.fields=none writes no fields: choose trainer.fields=final or all",
        )
    if s.optim.schedule == "constant":
        yield from _unused(
            s.optim,
            "optim",
            ["final_fraction"],
            "it is the cosine schedule's last rate: choose optim.schedule=cosine",
        )
    if s.logger.name == "none":
        yield from _unused(
            s.logger, "logger", ["mode", "project"], "logger=none logs nothing: choose logger=wandb"
        )
    task = s.task
    if hasattr(task, "eval_points") and getattr(task, "low", None) is None:
        yield from _unused(
            task,
            "task",
            ["eval_points"],
            "it spaces the evaluation over a box "
            "(task.low, task.high); named cases and a dataset are evaluated as "
            "they are",
        )


def _refuse(found: Unused) -> None:
    for path, value, why in found:
        raise ConfigError(f"{path}={value} has no effect: {why}")


def check_train(s) -> None:
    """nma.run's checked settings (a TrainConfig): every setting takes effect, and
    trainer.min_feature is one some design of the scene can meet."""
    _refuse(_physics(s, "nma.run"))
    _refuse(_training(s))
    check_min_feature(s)


def check_simulate(s) -> None:
    """nma.simulate's settings (a SimulateConfig): every setting takes effect."""
    _refuse(_physics(s, "nma.simulate"))


def check_export(s) -> None:
    """nma.export's settings (an ExportConfig, its format decided): every setting takes effect."""
    if not s.load_cases:
        _refuse(
            _unused(s, "", ["load_fraction"], "it sizes the load cases: give load_cases=true too")
        )
    if s.format != "stl" and not s.load_cases:
        _refuse(
            _unused(
                s,
                "",
                ["thickness"],
                "it is the STL's extrusion height and the load "
                f"cases' thickness; format={s.format} with load_cases=false uses neither",
            )
        )


def check_fit(s) -> None:
    """nma.fit's settings (a FitConfig): a number of terms only for the law that has terms."""
    if s.law != "ogden":
        _refuse(
            _unused(
                s,
                "",
                ["terms"],
                f"it is Ogden's number of terms, and law {s.law} has a "
                "fixed set of parameters: choose law=ogden, or leave terms out",
            )
        )


def ligament_bound(scene) -> tuple[float, str] | None:
    """An upper bound on the narrowest ligament any design of `scene` (a SceneConfig) can have, in
    its length units, and the ligament that sets it; None where no bound is known.

    Radii r >= lo (scene.radii_bounds[0]) put every point of a pore's side within (1 - lo) h of
    its cell's side, h the distance from the cell's centre to that side, and the side's curve
    crosses the perpendicular through the side's middle (nma.geometry.design.pore_nets).  So a
    pore of a cell beside the outer boundary (or a hole) is at most (1 - lo) h from it, and the
    pores of two neighbouring cells are at most (1 - lo) (h + h') apart.  Corner moves within
    scene.corner_box move every boundary point by at most sqrt(2) corner_box (each is a convex
    combination of the grid's nodes), so they widen a ligament by at most 2 sqrt(2) corner_box."""
    lo = scene.radii_bounds[0]
    rows = scene.rows()[::-1]  # bottom row first
    xb, yb = scene.breaks("x"), scene.breaks("y")
    nx, ny = len(rows[0]), len(rows)

    def token(i, j):  # None outside the grid
        return rows[j][i] if 0 <= i < nx and 0 <= j < ny else None

    def half(i, j, axis):
        b, k = (xb, i) if axis == 0 else (yb, j)
        return 0.5 * (b[k + 1] - b[k])

    best = None
    for j in range(ny):
        for i in range(nx):
            if token(i, j) != "P":
                continue
            for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                axis, there = (0 if di else 1), token(i + di, j + dj)
                h = half(i, j, axis)
                if there is None or (there == "." and not scene.central_pore):
                    found = ((1 - lo) * h, "a pore's wall to the outer boundary")
                elif there == "P":
                    found = (
                        (1 - lo) * (h + half(i + di, j + dj, axis)),
                        "the wall between two neighbouring pores",
                    )
                else:
                    continue  # a solid cell, or the central pore's patches: no bound from this side
                best = found if best is None or found[0] < best[0] else best
    if best is None:
        return None
    return best[0] + 2.0 * math.sqrt(2.0) * scene.corner_box, best[1]


def check_min_feature(s) -> None:
    """trainer.min_feature (mm) that no design of the scene can meet is refused, saying what the
    scene allows."""
    bound_mm, scale, scene = s.trainer.min_feature, s.part.scale, s.scene
    if bound_mm is None or scale is None:
        return
    if not scene.central_pore and not any(c in "P." for r in scene.rows() for c in r):
        raise ConfigError(
            f"trainer.min_feature={bound_mm:g} mm has no effect: scene {scene.name} "
            "has no pores, so no ligament for it to bound"
        )
    found = ligament_bound(scene)
    if found is None or bound_mm <= found[0] * scale:
        return
    width, what = found
    moved = (
        f", corners moved up to scene.corner_box={scene.corner_box:g}" if scene.corner_box else ""
    )
    raise ConfigError(
        f"trainer.min_feature={bound_mm:g} mm cannot be met by any design of scene {scene.name}: "
        f"its narrowest ligament is at most {width * scale:.4g} mm ({width:.4g} units at "
        f"part.scale={scale:g}: {what} at the smallest radius scene.radii_bounds[0]="
        f"{scene.radii_bounds[0]:g}{moved}); lower trainer.min_feature, or raise part.scale"
    )
