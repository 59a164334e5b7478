"""Every setting a config may leave to `auto`, decided in one place, and each part's own options of
the settings so decided: what a command does with its checked settings before it builds anything.

    settings = resolve(checked)               # once per command, where it checks its settings
    model_record(settings)                    # what was chosen: metrics.json's and nma.simulate's
    sim = Simulator.from_settings(settings)   # the parts' options: material_of, newton_options, ...

What auto decides, and by what:

- fidelity=scene (fidelity.ctrl_per_patch and quad_points null): the scene's own `fidelity`, else
  the paper's 5 x 5; fidelity=auto (fidelity.tolerance): the setting the scene's measured front
  picks, or the one a trained run's checkpoint records (nma.fidelity.resolve);
- material.formulation=auto, solver.corrector=auto, solver.max_iters, solver.max_step_iters and
  fidelity.inversion_barrier left null: by the material's compressibility (material_model: its nu
  against NEARLY_INCOMPRESSIBLE);
- contact=auto: on for a nearly incompressible material, else as the scene says (its `contact`);
- material.volumetric=auto: the form the scene states (its `volumetric`: the paper's scenes and
  strip state the paper's, bulk), else lame; a law without a volume term keeps auto (it has none).

Beside a trained run (nma.evaluate) what is left to auto is taken as the run solved, and
contact=auto follows the scene.  solver.linear=auto is the backend registry's choice
(nma.solver.linear), made where the simulator is built: it depends on the platform, not on the
settings.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, fields, replace
from typing import Any, Mapping

from .errors import ConfigError
from .mechanics.options import NEARLY_INCOMPRESSIBLE, ContactSettings
from .schema.material_model import COMPRESSIBLE, material_model
from .solver.options import NewtonOptions

AUTO_SOLVER = tuple(COMPRESSIBLE.solver)  # the solver settings auto decides by the material


def resolve(
    settings, chosen: tuple[int, int] | None = None, trained=None, contact_by_scene: bool = False
):
    """A command's checked settings with every choice left to auto made; stated choices are kept.

    Args:
        settings: Checked settings with `fidelity`, `contact` and `solver`, and `scene` and
            `material` unless `trained` is given (TrainConfig, SimulateConfig, EvaluateConfig).
        chosen: (control points, Gauss points) that fidelity=auto chose for a trained run, as its
            checkpoint records them: kept, whatever the fronts measured since would pick.
        trained: A trained run's resolved settings (nma.evaluate): the scene is its, and what
            `settings` leaves to auto is as the run solved (its inversion barrier, Newton's
            corrector and limits); a contact or solver left out (None) stays None, the run's own.
        contact_by_scene: contact=auto as the scene says, whatever the material
            (Simulator.from_config); beside a trained run it always is.

    Returns:
        The settings, of their own type, with every auto decided.

    Raises:
        ConfigError: fidelity=auto with no measured front for the scene or none within its
            tolerance, or a discretisation too large for this machine's memory.
    """
    from .fidelity import resolve as concrete

    if trained is None:
        scene, model = settings.scene, material_model(settings.material.nu)
        barrier, solver_choices = model.inversion_barrier, model.solver
    else:  # as the run solved: its material decided these
        scene, model = trained.scene, None
        barrier = trained.fidelity.inversion_barrier
        solver_choices = {k: getattr(trained.solver, k) for k in AUTO_SOLVER}
    fidelity = concrete(settings.fidelity, scene, chosen)
    if fidelity.inversion_barrier is None:
        fidelity = replace(fidelity, inversion_barrier=barrier)
    contact = settings.contact
    if contact is not None and contact.enabled is None:
        by_scene = contact_by_scene or model is None
        on = bool(scene.contact) if by_scene else model.contact_on(scene)
        contact = replace(contact, enabled=on)
    solver = settings.solver and _filled(settings.solver, solver_choices)
    decided = {"fidelity": fidelity, "contact": contact, "solver": solver}
    if model is not None:
        material = settings.material
        whole = not material.law_model().volume_term
        if material.formulation == "auto":  # a law without a volume term: displacement
            material = replace(material, formulation="displacement" if whole else model.formulation)
        if material.volumetric == "auto" and not whole:
            material = replace(material, volumetric=getattr(scene, "volumetric", None) or "lame")
        if material.volumetric == "lame" and not whole:
            _check_lame(material)
        decided["material"] = material
    return replace(settings, **decided)


def _check_lame(material) -> None:
    """Refuses a `lame` volume term whose coefficient is negative
    (Material.unbounded_volume_term), naming the settings."""
    problem = material_of(material).unbounded_volume_term(material_params(material), "material.")
    if problem:
        raise ConfigError(problem)


def _filled(solver, choices: dict):
    """`solver` with what it leaves to auto (corrector "auto", iteration limits None) taken from
    `choices`."""
    left = {k: v for k, v in choices.items() if getattr(solver, k) in (None, "auto")}
    return replace(solver, **left)


def model_record(settings) -> dict:
    """What resolved settings solve with, the choices auto made among them (metrics.json's `model`,
    nma.simulate's JSON): what a reader needs to know which model answered."""
    return {
        "nearly_incompressible": settings.material.nu >= NEARLY_INCOMPRESSIBLE,
        "formulation": settings.material.formulation,
        "corrector": settings.solver.corrector,
        "max_iters": settings.solver.max_iters,
        "max_step_iters": settings.solver.max_step_iters,
        "inversion_barrier": settings.fidelity.inversion_barrier,
        "contact": settings.contact.enabled,
    }


def describe_model(settings) -> str:
    """The model resolved settings solve with, in words (a log line)."""
    m = model_record(settings)
    return (
        f"material.formulation={m['formulation']}, solver.corrector={m['corrector']}, "
        f"solver.max_iters={m['max_iters']}, solver.max_step_iters={m['max_step_iters']}, "
        f"fidelity.inversion_barrier={m['inversion_barrier']:g}, "
        f"contact {'on' if m['contact'] else 'off'}"
    )


# -- each part's own options, of resolved settings ------------------------------------------------


def material_of(material):
    """The model's Material (nma.mechanics.material) of a resolved MaterialConfig: its law, its
    formulation and its volume term (volumetric=auto, of a material without a scene or of a law
    without a volume term, which ignores it: lame, auto's choice where no scene states one)."""
    from .mechanics.material import Material

    if material.formulation == "auto":
        raise ValueError(
            "material.formulation=auto is decided by the material: resolve it first "
            "(nma.resolve.resolve)"
        )
    volumetric = "lame" if material.volumetric == "auto" else material.volumetric
    return Material(material.formulation, material.law_model(), volumetric)


def material_params(material):
    """The parameter array every solve takes of a MaterialConfig: the law's parameters, then nu."""
    import jax.numpy as jnp

    from .runtime import configure_jax

    configure_jax()  # float64, as every solve
    values = material.values
    return jnp.array(
        [float(values[n]) for n in material.law_model().names] + [material.nu], dtype=jnp.float64
    )


def contact_options(contact) -> ContactSettings | None:
    """The contact model's own options of a resolved ContactConfig, or None with contact off."""
    if contact.enabled is None:
        raise ValueError(
            "contact=auto is decided by the material and the scene: resolve it first "
            "(nma.resolve.resolve)"
        )
    if not contact.enabled:
        return None
    return ContactSettings(**{f.name: getattr(contact, f.name) for f in fields(ContactSettings)})


def newton_options(solver) -> NewtonOptions:
    """Newton's own options of a SolverConfig; what is still left to auto (settings not resolved,
    as a script may hand nma.evaluate.evaluate) takes Newton's defaults, the compressible
    material's choice."""
    solver = _filled(solver, COMPRESSIBLE.solver)
    return NewtonOptions(**{f.name: getattr(solver, f.name) for f in fields(NewtonOptions)})


# -- Simulator.from_config's arguments as a command's settings ------------------------------------


@dataclass
class LibrarySettings:
    """Simulator.from_config's settings, as a command's: what resolve and from_settings read."""

    scene: Any
    fidelity: Any
    contact: Any
    solver: Any
    material: Any


def _mapping(argument: str, group: str, value):
    """One of from_config's arguments as a mapping: a preset's name (conf/<group>/<name>.yaml), a
    mapping, a checked schema instance or None (the defaults); anything else is refused, naming
    the argument."""
    if isinstance(value, str):
        from . import config

        return config.load(group, value)
    if value is None or isinstance(value, Mapping) or dataclasses.is_dataclass(value):
        return value
    raise TypeError(
        f"Simulator.from_config: {argument} must be a mapping, a {group} preset's name "
        f"(conf/{group}/) or None, got {type(value).__name__} {value!r:.80}"
    )


def library_settings(
    scene, fidelity=None, solver=None, contact=None, formulation: str = "auto", material=None
) -> LibrarySettings:
    """Simulator.from_config's arguments checked as the commands check them, and resolved:
    contact=auto as the scene says; what else is left to auto (the formulation, where neither the
    material nor `formulation` states one, Newton's corrector and limits, the inversion barrier) by
    the material's nu, as the commands decide it."""
    from .schema import ContactConfig, Fidelity, MaterialConfig, SolverConfig, build, scene_config

    scene, fidelity, solver, contact = (
        _mapping(name, name, value)
        for name, value in (
            ("scene", scene),
            ("fidelity", fidelity),
            ("solver", solver),
            ("contact", contact),
        )
    )
    scene = scene_config(scene)
    solver, contact = build(SolverConfig, solver), build(ContactConfig, contact)
    material = _mapping("material", "material", material) or {}
    if dataclasses.is_dataclass(material):
        material = dataclasses.asdict(material)
    material = build(MaterialConfig, material)
    if material.formulation == "auto":
        material = replace(material, formulation=formulation)
    return resolve(
        LibrarySettings(scene, build(Fidelity, fidelity), contact, solver, material),
        contact_by_scene=True,
    )
