"""The mechanical model's settings: material, discretisation (fidelity), contact, solver."""
from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any, ClassVar, Dict, List, Optional

from ..geometry.options import Resolution
from ..mechanics.options import (DENSITY_RANGE, FORMULATIONS, LAW_NAMES, MATERIAL_RANGES,
                                 NEARLY_INCOMPRESSIBLE, STRESS_UNITS, WAVE_SPEED_SQUARED_RANGE,
                                 ContactSettings)
from ..dynamics.options import RANGES, SCHEMES
from ..solver.options import CORRECTORS, WARM_START_NEEDS_HOST, NewtonOptions
from ..errors import ConfigError
from ..settings import Schema, bounded, choice, like, with_options


@dataclass
class MaterialConfig(Schema):
    """The material: a hyperelastic law with its parameters and Poisson's ratio (nma.mechanics.laws; the
    paper's: Neo-Hookean, E = 0.07, nu = 0.3).  `material=<law or elastomer>` picks a file of conf/material/."""
    prefix: ClassVar[str] = "material"
    law: str = choice("neo_hookean", LAW_NAMES, doc="neo_hookean takes E; the others their `parameters`")
    E: Optional[float] = bounded(0.07, MATERIAL_RANGES["E"], doc="Neo-Hookean's Young's modulus, in the unit of every "
                                 "force and stress; null for the other laws")
    nu: float = bounded(0.3, MATERIAL_RANGES["nu"],
        doc="0.5 is incompressible, which a displacement model cannot represent")
    parameters: Dict[str, float] = field(default_factory=dict, metadata={"doc": "the law's parameters by name: mooney_rivlin C10, C01; yeoh C10, C20, "
                                          "C30; ogden mu1, alpha1 (to mu3, alpha3); gent mu, Jm"})
    unit: Optional[str] = choice(None, (None, *STRESS_UNITS), doc="the unit of E and the parameters; null: the scene's own "
                                 "(forces then in E x length)")
    stretches: List[float] = bounded(factory=lambda: [0.5, 2.0], spec="(0, 100]", doc="principal stretches over which "
                                     "the law must be stable (Drucker's condition in uniaxial, equibiaxial and planar "
                                     "tension); a law unstable in them is refused")
    name: Optional[str] = None  # what the material is, in words (a shipped elastomer's product name)
    source: Optional[str] = None  # where the parameters come from: the data and the fit (conf/material/<elastomer>.yaml)
    fit: Dict[str, Any] = field(default_factory=dict, metadata={"doc": "the fit's record (nma.fit): data, range, errors"})
    density: float = bounded(1.0, DENSITY_RANGE, doc="mass per unit area, in the scene's units "
                             "(stress x time^2 / length^2): what dynamics and the natural "
                             "frequencies move; the shear modulus over it (a squared wave speed) "
                             "must lie in "
                             f"{WAVE_SPEED_SQUARED_RANGE}")
    formulation: str = choice("auto", ("auto", *FORMULATIONS), doc="mixed: the volume term at each element's mean "
                              "dilatation, which does not lock as nu -> 0.5 (nma.mechanics.energy); auto: mixed "
                              f"from nu {NEARLY_INCOMPRESSIBLE:g} on, else displacement (material_model)")

    def check(self):
        if self.law not in LAW_NAMES:
            self.fail("law", f"must be one of {list(LAW_NAMES)}", self.law)
        if len(self.stretches) != 2 or not self.stretches[0] < 1.0 < self.stretches[1]:
            self.fail("stretches", "must be [low, high] with low < 1 < high", self.stretches)
        if self.law == "neo_hookean":
            if self.E is None:
                self.fail("E", "must be given for law neo_hookean (in " + MATERIAL_RANGES["E"] + ")", self.E)
            if self.parameters:
                self.fail("parameters", "are the other laws'; neo_hookean takes E", dict(self.parameters))
        else:
            if self.E is not None:
                self.fail("E", f"is Neo-Hookean's; law {self.law} takes material.parameters: choose material={self.law} "
                          "(its file sets them), or set material.E=null and the parameters", self.E)
            from ..mechanics.laws import law_of  # JAX: only for the laws that need a stability check
            law_of(self.law, self.parameters).check(dict(self.parameters), self.nu, tuple(self.stretches))
        self._check_density()

    def _check_density(self):
        """The density against the initial shear modulus mu0: mu0 / density (a squared wave speed,
        which sets the natural frequencies and the time step) in WAVE_SPEED_SQUARED_RANGE."""
        if self.law == "neo_hookean":
            mu0 = self.E / (2.0 * (1.0 + self.nu))
        else:
            import numpy as np
            from ..mechanics.laws import law_of
            law = law_of(self.law, self.parameters)
            mu0 = float(law.shear_modulus(np.array([float(self.parameters[n]) for n in law.names])))
        if not mu0 > 0:  # the law's own checks speak of it
            return
        lo, hi = (float(v) for v in WAVE_SPEED_SQUARED_RANGE[1:-1].split(","))
        d_lo, d_hi = (float(v) for v in DENSITY_RANGE[1:-1].split(","))
        allowed = f"[{max(d_lo, mu0 / hi):.3g}, {min(d_hi, mu0 / lo):.3g}]"
        if not lo <= mu0 / self.density <= hi:
            self.fail("density", f"must be in {allowed} for this material: its shear modulus "
                      f"{mu0:.3g} over the density (a squared wave speed) must lie in "
                      f"{WAVE_SPEED_SQUARED_RANGE}, where the mass matrix and the natural "
                      "frequencies stay within float64", self.density)

    @property
    def values(self) -> dict:
        """The law's parameters by name (Neo-Hookean's E)."""
        return {"E": self.E} if self.law == "neo_hookean" else dict(self.parameters)

    def record(self) -> dict:
        """The law, its parameters, nu, the formulation and the unit: what a result says it was solved with."""
        unit = {"unit": self.unit} if self.unit else {}
        return {**({"name": self.name} if self.name else {}), "law": self.law, **self.values, "nu": self.nu, "formulation": self.formulation, **unit}

    def model(self):
        """The model's Material: the law and the formulation (auto resolved first: resolve_auto)."""
        from ..mechanics.laws import law_of
        from ..mechanics.material import Material
        if self.formulation == "auto":
            raise ValueError("material.formulation=auto is decided by the material: resolve it first (resolve_auto)")
        return Material(self.formulation, law_of(self.law, self.values))

    def params(self):
        """The parameter array every solve takes: the law's parameters, then nu."""
        import jax.numpy as jnp
        from ..mechanics.laws import law_of
        from ..runtime import configure_jax
        configure_jax()  # float64, as every solve
        return jnp.array([float(self.values[n]) for n in law_of(self.law, self.values).names] + [self.nu],
                         dtype=jnp.float64)


@dataclass
class DynamicsConfig(Schema):
    """Inertia and damping (nma.dynamics): implicit time stepping in place of static equilibrium.  `off`
    (the default) is the static model; `dynamics=newmark` or `dynamics=generalised_alpha` moves the scene
    through time, each step a Newton solve with the static solver's safeguards."""
    prefix: ClassVar[str] = "dynamics"
    scheme: str = choice("off", ("off", *SCHEMES), doc="newmark: average acceleration (no numerical damping); "
                         "generalised_alpha: second order, high frequencies damped to rho_inf")
    rho_inf: float = bounded(0.8, RANGES["rho_inf"], doc="generalised_alpha's spectral radius at infinite frequency (1: none "
                             "damped, 0: damped at once)")
    dt: Optional[float] = bounded(None, RANGES["dt"], doc="the time step; null: a 20th of the lowest natural period "
                                  "at rest")
    steps: int = bounded(100, RANGES["steps"], doc="time steps")
    alpha: float = bounded(0.0, RANGES["alpha"], doc="Rayleigh damping's mass-proportional part, C = alpha M + beta K_0")
    beta: float = bounded(0.0, RANGES["beta"], doc="Rayleigh damping's stiffness-proportional part (K_0: the tangent at rest)")
    damping_ratio: Optional[float] = bounded(None, "[0, 1]", doc="in place of alpha and beta: this ratio of critical "
                                             "damping at damping_frequency (alpha = zeta omega, beta = zeta / omega)")
    damping_frequency: Optional[float] = bounded(None, "(0, inf)", doc="the angular frequency damping_ratio holds at "
                                                 "(rad per unit time); null: the lowest natural frequency at rest")
    ramp: Optional[float] = bounded(None, "[0, inf)", doc="nma.simulate: the time over which the actuation rises "
                                    "(a smootherstep) and then holds; null: the lowest natural period")
    max_cuts: int = bounded(4, RANGES["max_cuts"], doc="a time step that fails is redone in 2, 4, ... 2^max_cuts steps")

    def check(self):
        if self.damping_ratio is not None and (self.alpha or self.beta):
            self.fail("damping_ratio", "replaces alpha and beta: give one or the other", self.damping_ratio)

    @property
    def enabled(self) -> bool:
        return self.scheme != "off"


@dataclass
class PartConfig(Schema):
    """The physical part a scene's design becomes: its size and thickness in millimetres.  With both, and a
    material whose stresses are in a physical unit (material.unit), lengths are reported in mm and forces in
    N (a plane-strain force per unit thickness, times the thickness)."""
    prefix: ClassVar[str] = "part"
    scale: Optional[float] = bounded(None, "[0.001, 10000]", doc="millimetres per length unit of the scene; null: "
                                     "lengths stay in the scene's units")
    thickness: Optional[float] = bounded(None, "[0.001, 100000]", doc="the part's thickness (out of plane) in "
                                         "millimetres; null: forces stay per unit thickness")


_RESOLUTION = Resolution()  # the discretisation's defaults


@dataclass
class Fidelity(Schema):
    """The speed/accuracy knobs of a discretisation (the paper's: 5 control points, 5 Gauss points); each
    of the discretisation's own declared once in nma/geometry/options.py (Resolution)."""
    prefix: ClassVar[str] = "fidelity"
    # None (fidelity=scene, the commands' default): the scene's own (its `fidelity` field), else the
    # paper's; resolve it first (nma.fidelity.resolve)
    ctrl_per_patch: Optional[int] = like(Resolution, "ctrl_per_patch")
    quad_points: Optional[int] = like(Resolution, "quad_points")
    tolerance: Optional[float] = bounded(None, "(0, inf)", doc="fidelity=auto: the largest relative gradient "
                                         "error allowed against the 14 x 5 reference; the scene's measured front "
                                         "then sets the two above")
    inversion_barrier: Optional[float] = like(Resolution, "inversion_barrier", None,
                                              doc="None (auto): by the material (material_model)")
    grading: float = like(Resolution, "grading")

    @property
    def concrete(self) -> bool:
        """Both halves set (not left to the scene by fidelity=scene)."""
        return self.ctrl_per_patch is not None and self.quad_points is not None

    def check(self):
        if self.concrete:
            Resolution.of(self)  # the discretisation's own rules (3k + 2 control points)
        if self.tolerance is not None and self.grading != 1.0:
            raise ConfigError(f"fidelity.grading={self.grading:g} with fidelity=auto (fidelity.tolerance): the fronts it "
                              "picks from are measured with uniform knots; set fidelity.ctrl_per_patch and "
                              "fidelity.quad_points yourself, or leave fidelity.grading at 1")

    def of_scene(self, scene) -> "Fidelity":
        """These settings with what fidelity=scene leaves open (None) taken from the scene's own `fidelity`
        (the discretisation its reproduction trains at), else the paper's 5 x 5."""
        if self.concrete:
            return self
        own = {"ctrl_per_patch": _RESOLUTION.ctrl_per_patch, "quad_points": _RESOLUTION.quad_points, **scene.fidelity}
        return replace(self, **{k: v for k, v in own.items() if getattr(self, k) is None})


@dataclass
@with_options(ContactSettings)  # the contact model's settings, declared once in nma/mechanics/options.py
class ContactConfig(Schema):
    """The pores' self-contact (nma.mechanics.contact): a barrier between each pore's walls, so that a
    closing pore's walls touch instead of passing through each other; nothing changes while they are
    further apart than `distance`."""
    prefix: ClassVar[str] = "contact"
    enabled: Optional[bool] = False  # None (contact=auto): as the scene says (SceneConfig.contact); resolved()

    def resolved(self, scene) -> "ContactConfig":
        """These settings with contact=auto (enabled None) decided by the scene's own default (its
        `contact` field: on for the scenes whose pores close under their tasks' actuations)."""
        return self if self.enabled is not None else replace(self, enabled=bool(scene.contact))

    def settings(self) -> Optional[ContactSettings]:
        """The model's own options, or None with contact off."""
        if self.enabled is None:
            raise ValueError("contact=auto is decided by the scene: resolve it first (ContactConfig.resolved)")
        if not self.enabled:
            return None
        return ContactSettings(**{f.name: getattr(self, f.name) for f in fields(ContactSettings)})


@dataclass
@with_options(NewtonOptions)  # every Newton setting, declared once in nma/solver/options.py
class SolverConfig(Schema):
    """Newton with adaptive load steps (nma.solver.newton) and the linear solver under it."""
    prefix: ClassVar[str] = "solver"
    max_iters: Optional[int] = like(NewtonOptions, "max_iters", None, doc="None (auto): by the material "
                                    "(material_model)")
    max_step_iters: Optional[int] = like(NewtonOptions, "max_step_iters", None, doc="None (auto): by the material")
    corrector: str = like(NewtonOptions, "corrector", "auto", doc="auto: by the material (material_model)",
                          choices=("auto", *CORRECTORS.names()))
    linear: str = "auto"   # a linear backend registered in nma.solver.linear (auto, pardiso, superlu, dense)
    workers: int = bounded(0, "[0, 1024]", doc="threads solving a batch's samples at once; 0 = one per core")

    def check(self):
        if self.warm_start and self.linear == "dense":  # the one traceable backend (nma.solver.linear)
            self.fail("warm_start", WARM_START_NEEDS_HOST)

    def filled(self, choices: dict) -> "SolverConfig":
        """These settings with what is left to auto (corrector "auto", iteration limits None) taken from
        `choices` (a MaterialModel's solver, or another run's resolved settings)."""
        return replace(self, **{k: v for k, v in choices.items() if getattr(self, k) in (None, "auto")})

    def newton(self) -> NewtonOptions:
        """Newton's own settings, handed to the solver; what is left to auto takes the compressible
        material's choice (Newton's defaults) unless resolve_auto decided it by the material."""
        resolved = self.filled(COMPRESSIBLE.solver)
        return NewtonOptions(**{f.name: getattr(resolved, f.name) for f in fields(NewtonOptions)})


@dataclass(frozen=True)
class MaterialModel:
    """What the auto settings choose for a material: its formulation, Newton's corrector and iteration
    limits, the inversion barrier and whether the pores' walls touch (None: as the scene says)."""
    formulation: str
    solver: dict
    inversion_barrier: float
    contact: Optional[bool]


# A compressible material: the displacement model and Newton's defaults.  A nearly incompressible one
# (nu >= NEARLY_INCOMPRESSIBLE): the locking-free model with the settings under which every cell of the
# stability map at nu 0.499 converges (make study-incompressible; docs/how-to/nearly-incompressible.md).
_NEWTON = NewtonOptions()  # Newton's defaults: what auto chooses for a compressible material
COMPRESSIBLE = MaterialModel("displacement", {"corrector": _NEWTON.corrector, "max_iters": _NEWTON.max_iters,
                                              "max_step_iters": _NEWTON.max_step_iters}, 0.0, None)
NEARLY_INCOMPRESSIBLE_MODEL = MaterialModel("mixed", {"corrector": "trust_region", "max_iters": 1000,
                                                      "max_step_iters": 300}, 0.5, True)


def material_model(nu: float) -> MaterialModel:
    """The model a material of Poisson's ratio nu needs: what material.formulation=auto, solver.corrector=auto,
    solver.max_iters, solver.max_step_iters and fidelity.inversion_barrier left unset, and contact=auto, take."""
    return NEARLY_INCOMPRESSIBLE_MODEL if nu >= NEARLY_INCOMPRESSIBLE else COMPRESSIBLE


def auto_contact(settings) -> bool:
    """contact=auto decided: by the material's compressibility, or by the scene where it leaves it open."""
    model = material_model(settings.material.nu)
    return bool(settings.scene.contact) if model.contact is None else model.contact


def resolve_auto(settings):
    """Command settings (material, fidelity, solver, contact, scene) with every choice left to auto made:
    by the material's compressibility (material_model) and, for contact, by the scene where the material
    leaves it open.  Stated choices are kept."""
    model = material_model(settings.material.nu)
    material, fidelity, contact = settings.material, settings.fidelity, settings.contact
    if material.formulation == "auto":
        material = replace(material, formulation=model.formulation)
    if fidelity.inversion_barrier is None:
        fidelity = replace(fidelity, inversion_barrier=model.inversion_barrier)
    if contact.enabled is None:
        contact = replace(contact, enabled=auto_contact(settings))
    return replace(settings, material=material, solver=settings.solver.filled(model.solver), fidelity=fidelity,
                   contact=contact)


def model_record(settings) -> dict:
    """The modelling choices resolved settings solve with, the auto ones among them (metrics.json, the
    JSON of nma.simulate): what a reader needs to know which model answered."""
    return {"nearly_incompressible": settings.material.nu >= NEARLY_INCOMPRESSIBLE,
            "formulation": settings.material.formulation, "corrector": settings.solver.corrector,
            "max_iters": settings.solver.max_iters, "max_step_iters": settings.solver.max_step_iters,
            "inversion_barrier": settings.fidelity.inversion_barrier, "contact": settings.contact.enabled}


def describe_model(settings) -> str:
    """The model resolved settings solve with, in words (a log line)."""
    m = model_record(settings)
    return (f"material.formulation={m['formulation']}, solver.corrector={m['corrector']}, solver.max_iters="
            f"{m['max_iters']}, solver.max_step_iters={m['max_step_iters']}, fidelity.inversion_barrier="
            f"{m['inversion_barrier']:g}, contact {'on' if m['contact'] else 'off'}")
