"""The mechanical model's settings: material, discretisation (fidelity), contact, solver."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, Dict, List, Optional

from ..geometry.options import Resolution
from ..mechanics.laws import POISSON, law_of
from ..mechanics.options import (
    DENSITY_RANGE,
    FORMULATIONS,
    LAW_NAMES,
    NEARLY_INCOMPRESSIBLE,
    STRESS_UNITS,
    VOLUMETRIC,
    WAVE_SPEED_SQUARED_RANGE,
    ContactSettings,
)
from ..dynamics.options import ADJOINTS, CONTROLLERS, SCHEMES, DynamicsOptions
from ..solver.options import CORRECTORS, WARM_START_NEEDS_HOST, NewtonOptions
from ..errors import ConfigError
from ..settings import Schema, bounded, choice, like, option, with_options


# the Neo-Hookean law's Young's modulus, which a config gives as material.E (the paper's setting)
_E = law_of("neo_hookean").declared("E")


@dataclass
class MaterialConfig(Schema):
    """The material: a hyperelastic law with its parameters and Poisson's ratio (nma.mechanics.laws;
    the paper's: Neo-Hookean, E = 0.07, nu = 0.3).  `material=<law or elastomer>` picks a file of
    conf/material/.  Each law declares its parameters with their defaults, ranges and meanings (its
    module of nma/mechanics/laws/); this schema checks a material against that declaration."""

    prefix: ClassVar[str] = "material"
    law: str = choice(
        "neo_hookean", LAW_NAMES, doc="its parameters: the Material laws section below"
    )
    E: Optional[float] = bounded(
        _E.default,
        _E.range,
        doc=f"{_E.doc}: the parameter E of a law that takes one (neo_hookean, "
        "st_venant_kirchhoff); null for the other laws",
    )
    nu: float = bounded(POISSON.default, POISSON.range, doc=POISSON.doc)
    parameters: Dict[str, float] = field(
        default_factory=dict,
        metadata={
            "doc": "the law's parameters by name (the Material laws section below); none given: "
            "the law's defaults"
        },
    )
    unit: Optional[str] = choice(
        None,
        (None, *STRESS_UNITS),
        doc="the unit of E and the parameters; null: the scene's own (forces then in E x length)",
    )
    stretches: List[float] = bounded(
        factory=lambda: [0.5, 2.0],
        spec="(0, 100]",
        doc="principal stretches over which the law "
        "must be stable (Drucker's condition in uniaxial, equibiaxial and planar tension); a law "
        "unstable in them is refused",
    )
    name: Optional[str] = option(
        None, "what the material is, in words (a shipped elastomer's product name)"
    )
    source: Optional[str] = option(
        None,
        "where the parameters come from: the data and the fit (conf/material/<elastomer>.yaml)",
    )
    fit: Dict[str, Any] = field(
        default_factory=dict, metadata={"doc": "the fit's record (nma.fit): data, range, errors"}
    )
    density: float = bounded(
        1.0,
        DENSITY_RANGE,
        doc="mass per unit area, in the scene's units "
        "(stress x time^2 / length^2): what dynamics and the natural "
        "frequencies move; the shear modulus over it (a squared wave speed) must lie in "
        f"{WAVE_SPEED_SQUARED_RANGE}",
    )
    formulation: str = choice(
        "auto",
        ("auto", *FORMULATIONS),
        doc="mixed: the volume term at each "
        "element's mean dilatation, which does not lock as nu -> 0.5 "
        "(nma.mechanics.energy); auto: mixed from nu "
        f"{NEARLY_INCOMPRESSIBLE:g} on, else displacement (material_model); a law without "
        "a volume term (st_venant_kirchhoff): displacement",
    )
    volumetric: str = choice(
        "auto",
        ("auto", *VOLUMETRIC),
        doc="the coefficient of the volume term k/2 (log J)^2: lame, the Lame constant that "
        "makes nu the 3D Poisson's ratio (plane strain then has E / (1 - nu^2) and nu / (1 - nu) "
        "under uniaxial stress); bulk, the bulk modulus E / (3 (1 - 2 nu)), the paper's form "
        "(1.064 E / (1 - nu^2) and 0.52 at nu = 0.3); auto: the scene's (scene.volumetric; the "
        "paper's scenes and strip state bulk), else lame; a law without a volume term "
        "(st_venant_kirchhoff): auto only",
    )

    def check(self):
        if len(self.stretches) != 2 or not self.stretches[0] < 1.0 < self.stretches[1]:
            self.fail("stretches", "must be [low, high] with low < 1 < high", self.stretches)
        if self.E is not None and "E" in self.parameters:
            self.fail(
                "E", "is given twice, as material.E and material.parameters.E: give one", self.E
            )
        law = self.law_model()
        if self.E is not None and "E" not in law.names:
            self.fail(
                "E",
                f"is not a parameter of law {self.law}, which takes material.parameters "
                f"{list(law.names)}: choose material={self.law} (its file sets them), or set "
                "material.E=null and the parameters (none: the law's defaults)",
                self.E,
            )
        if self.volumetric != "auto" and not law.volume_term:
            self.fail(
                "volumetric",
                f"has no effect: law {self.law} has no volume term (its energy is whole); "
                "leave material.volumetric=auto",
                self.volumetric,
            )
        law.check(self.values, self.nu)
        if not law.stable:
            from ..mechanics.laws.homogeneous import check_stable  # JAX: it evaluates the law

            check_stable(law, self.values, tuple(self.stretches))
        self._check_density(law)

    def _check_density(self, law):
        """The density against the initial shear modulus mu0: mu0 / density (a squared wave speed,
        which sets the natural frequencies and the time step) in WAVE_SPEED_SQUARED_RANGE."""
        mu0 = float(law.shear_modulus({**self.values, POISSON.name: self.nu}))
        lo, hi = (float(v) for v in WAVE_SPEED_SQUARED_RANGE[1:-1].split(","))
        d_lo, d_hi = (float(v) for v in DENSITY_RANGE[1:-1].split(","))
        allowed = f"[{max(d_lo, mu0 / hi):.3g}, {min(d_hi, mu0 / lo):.3g}]"
        if not lo <= mu0 / self.density <= hi:
            self.fail(
                "density",
                f"must be in {allowed} for this material: its shear modulus "
                f"{mu0:.3g} over the density (a squared wave speed) must lie in "
                f"{WAVE_SPEED_SQUARED_RANGE}, where the mass matrix and the natural "
                "frequencies stay within float64",
                self.density,
            )

    @classmethod
    def of_law(cls, name: str) -> "MaterialConfig":
        """The material of law `name` with its declared defaults (conf/material/<name>.yaml): a
        parameter that is a field here (E) given there, the others in `parameters`."""
        return cls(**cls.fields_of_law(name))

    @classmethod
    def fields_of_law(cls, name: str) -> dict:
        """of_law's fields, unchecked (what Hydra's store holds for a law without a file)."""
        values, own = law_of(name).defaults(), set(cls.__dataclass_fields__)
        top = {n: values.pop(n) for n in list(values) if n in own}
        stretches = list(law_of(name).stretch_range)
        return dict(law=name, parameters=values, stretches=stretches, **{"E": None, **top})

    @property
    def values(self) -> dict:
        """The law's parameters by name: `parameters` and E where given; none given, the law's
        declared defaults."""
        given = {**self.parameters, **({"E": self.E} if self.E is not None else {})}
        return given or law_of(self.law).defaults()

    def law_model(self):
        """The law (nma.mechanics.laws.Law) taking these parameters (Ogden's terms)."""
        return law_of(self.law, self.values)

    def record(self) -> dict:
        """The law, its parameters, nu, the formulation, the volume term and the unit: what a result
        says it was solved with."""
        unit = {"unit": self.unit} if self.unit else {}
        return {
            **({"name": self.name} if self.name else {}),
            "law": self.law,
            **self.values,
            "nu": self.nu,
            "formulation": self.formulation,
            "volumetric": self.volumetric,
            **unit,
        }


@dataclass
class DynamicsConfig(Schema):
    """Inertia and damping (nma.dynamics): implicit time stepping in place of static equilibrium.
    `off` (the default) is the static model; `dynamics=newmark` or `dynamics=generalised_alpha`
    moves the scene through time, each step a Newton solve with the static solver's safeguards.  The
    time stepping's own settings are declared once in nma/dynamics/options.py (DynamicsOptions), the
    library's defaults too."""

    prefix: ClassVar[str] = "dynamics"
    scheme: str = like(
        DynamicsOptions,
        "scheme",
        "off",
        doc="off: the static model",
        choices=("off", *SCHEMES.names()),
    )
    rho_inf: float = like(DynamicsOptions, "rho_inf")
    dt: Optional[float] = like(DynamicsOptions, "dt")
    steps: int = like(DynamicsOptions, "steps")
    alpha: float = like(DynamicsOptions, "alpha")
    beta: float = like(DynamicsOptions, "beta")
    damping_ratio: Optional[float] = bounded(
        None,
        "[0, 1]",
        doc="in place of alpha and beta: this ratio of critical "
        "damping at damping_frequency (alpha = zeta omega, beta = zeta / omega)",
    )
    damping_frequency: Optional[float] = bounded(
        None,
        "(0, inf)",
        doc="the angular frequency damping_ratio holds at "
        "(rad per unit time); null: the lowest natural frequency at rest",
    )
    ramp: Optional[float] = bounded(
        None,
        "[0, inf)",
        doc="nma.simulate: the time over which the actuation rises "
        "(a smootherstep) and then holds; null: the lowest natural period",
    )
    max_cuts: int = like(DynamicsOptions, "max_cuts")
    controller: str = like(DynamicsOptions, "controller", choices=tuple(CONTROLLERS.names()))
    rtol: float = like(DynamicsOptions, "rtol")
    atol: float = like(DynamicsOptions, "atol")
    adjoint: str = like(DynamicsOptions, "adjoint", choices=tuple(ADJOINTS.names()))
    checkpoints: Optional[int] = like(DynamicsOptions, "checkpoints")
    start: str = like(DynamicsOptions, "start")

    # settings each part alone takes: (the part's setting, its value there, the settings)
    PART_SETTINGS: ClassVar[tuple] = (
        ("controller", "adaptive", ("rtol", "atol")),
        ("controller", ("cuts", "adaptive"), ("max_cuts",)),
        ("adjoint", "checkpointed", ("checkpoints",)),
    )

    def check(self):
        if self.damping_ratio is not None and (self.alpha or self.beta):
            self.fail(
                "damping_ratio",
                "replaces alpha and beta: give one or the other",
                self.damping_ratio,
            )
        defaults = DynamicsOptions()
        for part, takes, names in self.PART_SETTINGS if self.enabled else ():
            takes = (takes,) if isinstance(takes, str) else takes
            if getattr(self, part) in takes:
                continue
            for name in names:
                if getattr(self, name) != getattr(defaults, name):
                    raise ConfigError(
                        f"dynamics.{name}={getattr(self, name)!r} has no effect: "
                        f"only the {part} {' or '.join(takes)} takes it, and "
                        f"dynamics.{part} is {getattr(self, part)}"
                    )

    @property
    def enabled(self) -> bool:
        return self.scheme != "off"


@dataclass
class PartConfig(Schema):
    """The physical part a scene's design becomes: its size and thickness in millimetres.  With
    both, and a material whose stresses are in a physical unit (material.unit), lengths are reported
    in mm and forces in N (a plane-strain force per unit thickness, times the thickness)."""

    prefix: ClassVar[str] = "part"
    scale: Optional[float] = bounded(
        None,
        "[0.001, 10000]",
        doc="millimetres per length unit of the scene; null: lengths stay in the scene's units",
    )
    thickness: Optional[float] = bounded(
        None,
        "[0.001, 100000]",
        doc="the part's thickness (out of plane) in "
        "millimetres; null: forces stay per unit thickness",
    )


@dataclass
class Fidelity(Schema):
    """The speed/accuracy knobs of a discretisation (the paper's: 5 control points, 5 Gauss points);
    each of the discretisation's own declared once in nma/geometry/options.py (Resolution)."""

    prefix: ClassVar[str] = "fidelity"
    # None (fidelity=scene, the commands' default): the scene's own (its `fidelity` field), else the
    # paper's; resolve it first (nma.fidelity.resolve)
    ctrl_per_patch: Optional[int] = like(Resolution, "ctrl_per_patch")
    quad_points: Optional[int] = like(Resolution, "quad_points")
    tolerance: Optional[float] = bounded(
        None,
        "(0, inf)",
        doc="fidelity=auto: the largest relative gradient "
        "error allowed against the 14 x 5 reference; the scene's measured front "
        "then sets the two above",
    )
    inversion_barrier: Optional[float] = like(
        Resolution, "inversion_barrier", None, doc="None (auto): by the material (material_model)"
    )
    grading: float = like(Resolution, "grading")

    @property
    def concrete(self) -> bool:
        """Both halves set (not left to the scene by fidelity=scene)."""
        return self.ctrl_per_patch is not None and self.quad_points is not None

    def check(self):
        if self.concrete:
            Resolution.of(self)  # the discretisation's own rules (3k + 2 control points)
        if self.tolerance is not None and self.grading != 1.0:
            raise ConfigError(
                f"fidelity.grading={self.grading:g} with fidelity=auto (fidelity.tolerance): the "
                "fronts it "
                "picks from are measured with uniform knots; set fidelity.ctrl_per_patch and "
                "fidelity.quad_points yourself, or leave fidelity.grading at 1"
            )


@dataclass
# the contact model's settings, declared once in nma/mechanics/options.py
@with_options(ContactSettings)
class ContactConfig(Schema):
    """The pores' self-contact (nma.mechanics.contact): a barrier between each pore's walls, so that
    a closing pore's walls touch instead of passing through each other; nothing changes while they
    are further apart than `distance`."""

    prefix: ClassVar[str] = "contact"
    enabled: Optional[bool] = option(
        False,
        "None (contact=auto): on for a nearly incompressible "
        "material, else as the scene says (SceneConfig.contact)",
    )


@dataclass
@with_options(NewtonOptions)  # every Newton setting, declared once in nma/solver/options.py
class SolverConfig(Schema):
    """Newton with adaptive load steps (nma.solver.newton) and the linear solver under it."""

    prefix: ClassVar[str] = "solver"
    max_iters: Optional[int] = like(
        NewtonOptions, "max_iters", None, doc="None (auto): by the material (material_model)"
    )
    max_step_iters: Optional[int] = like(
        NewtonOptions, "max_step_iters", None, doc="None (auto): by the material"
    )
    corrector: str = like(
        NewtonOptions,
        "corrector",
        "auto",
        doc="auto: by the material (material_model)",
        choices=("auto", *CORRECTORS.names()),
    )
    # a linear backend registered in nma.solver.linear (auto, pardiso, superlu, dense)
    linear: str = "auto"
    workers: int = bounded(
        0, "[0, 1024]", doc="threads solving a batch's samples at once; 0 = one per core"
    )

    def check(self):
        # the one traceable backend (nma.solver.linear)
        if self.warm_start and self.linear == "dense":
            self.fail("warm_start", WARM_START_NEEDS_HOST)
