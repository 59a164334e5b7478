"""The commands' top-level configs: each groups the schemas a command reads."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any, ClassVar, List, Optional

from omegaconf import MISSING

from ..errors import ConfigError
from ..mechanics.laws import LAWS
from ..mechanics.options import LAW_NAMES, MATERIAL_RANGES, MODES, STRESS_UNITS
from ..settings import Schema, bounded, choice, option
from .physics import (
    ContactConfig,
    DynamicsConfig,
    Fidelity,
    MaterialConfig,
    PartConfig,
    SolverConfig,
)
from .effect import check_fit, check_simulate
from .periodic import LOAD_KINDS, LoadConfig
from .scene import SceneConfig
from ..tasks.schemas import TASK_SCHEMAS, TaskConfig
from .training import LoggerConfig, ModelConfig, OptimConfig, TrainerConfig


@dataclass
class TrainConfig:
    """`python -m nma.run`: every group of a training run."""

    task: Any = MISSING  # a TaskConfig subclass, chosen by the task group
    scene: SceneConfig = MISSING
    fidelity: Fidelity = field(default_factory=Fidelity)
    contact: ContactConfig = field(default_factory=ContactConfig)
    solver: SolverConfig = field(default_factory=SolverConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    trainer: TrainerConfig = field(default_factory=TrainerConfig)
    logger: LoggerConfig = field(default_factory=LoggerConfig)
    material: MaterialConfig = field(default_factory=MaterialConfig)
    part: PartConfig = field(default_factory=PartConfig)
    dynamics: DynamicsConfig = field(default_factory=DynamicsConfig)

    def __post_init__(self):
        if not isinstance(self.task, TaskConfig):
            raise ConfigError(f"task must be one of {sorted(TASK_SCHEMAS)}")
        periodic = bool(getattr(self.task, "periodic", False))
        if self.scene.periodic != periodic:
            raise ConfigError(
                f"scene={self.scene.name} is periodic (a cell tiled without end, loaded by F_bar) "
                f"and task {self.task.factory} trains on a finite scene held by its supports; a "
                f"periodic scene's response: python -m nma.simulate scene={self.scene.name} "
                "load=uniaxial_y (docs/how-to/periodic-metamaterials.md)"
                if self.scene.periodic
                else f"task {self.task.factory} trains a periodic cell: scene={self.scene.name} is "
                "finite (give a periodic scene: scene.periodic=true)"
            )
        if self.task.name != self.scene.name:
            raise ConfigError(
                f"scene={self.scene.name} does not fit task={self.task.name}; "
                f"each task runs on its scene of the same name"
            )
        if hasattr(self.task, "check_scene"):
            self.task.check_scene(self.scene)
        if hasattr(self.task, "check_optim"):
            self.task.check_optim(self.optim)
        in_time = getattr(self.task, "in_time", False)
        if in_time and not self.dynamics.enabled:
            raise ConfigError(
                f"task {self.task.factory} moves in time: choose dynamics=newmark or "
                f"dynamics=generalised_alpha (dynamics.scheme is off)"
            )
        if in_time:
            self.task.check_dynamics(self.dynamics)
        if self.dynamics.enabled and not in_time:
            raise ConfigError(
                f"dynamics.scheme={self.dynamics.scheme}: task {self.task.factory} is static (its "
                f"goal is an equilibrium); the tasks in time are in docs/reference/tasks.md"
            )
        # a size in mm needs the part's scale
        if self.trainer.min_feature is not None and self.part.scale is None:
            raise ConfigError(
                f"trainer.min_feature={self.trainer.min_feature} (mm) needs part.scale, the "
                "millimetres "
                "per length unit of the scene (e.g. part.scale=2: a paper cell of 5 units is 10 mm)"
            )


@dataclass
class OutputConfig(Schema):
    prefix: ClassVar[str] = "output"
    samples: int = bounded(
        9, "[2, 64]", doc="material points per patch side in the fields and figure"
    )
    figure: bool = True


@dataclass
class SimulateConfig:
    """`python -m nma.simulate`: one static solve, or with dynamics the actuation applied over
    time."""

    scene: SceneConfig = MISSING
    fidelity: Fidelity = field(default_factory=Fidelity)
    contact: ContactConfig = field(default_factory=ContactConfig)
    solver: SolverConfig = field(default_factory=SolverConfig)
    material: MaterialConfig = field(default_factory=MaterialConfig)
    part: PartConfig = field(default_factory=PartConfig)
    dynamics: DynamicsConfig = field(default_factory=DynamicsConfig)
    # one value per actuation of the scene; null means all zero
    actuation: Optional[List[float]] = None
    # load=<kind>: a periodic scene's macroscopic load path (conf/load/); null: a finite scene's
    load: Optional[LoadConfig] = None
    output: OutputConfig = field(default_factory=OutputConfig)

    def __post_init__(self):
        check_simulate(self)
        if self.scene.periodic:
            self._check_periodic()
        elif self.load is not None:
            raise ConfigError(
                f"load={self.load.kind} loads a periodic scene, and scene={self.scene.name} is "
                "finite (held by its supports, moved by actuation=[...]): leave load out, or "
                "choose a periodic scene (scene.periodic=true, e.g. scene=square_array)"
            )
        if self.actuation is None:
            return
        if not all(math.isfinite(a) for a in self.actuation):
            raise ConfigError(f"actuation must be finite numbers, got {self.actuation}")
        if len(self.actuation) != self.scene.n_actuations:
            raise ConfigError(
                f"actuation must have {self.scene.n_actuations} entries for scene "
                f"{self.scene.name}, got {len(self.actuation)}: {self.actuation}"
            )

    def _check_periodic(self):
        """A periodic scene follows a load path: no actuation, no dynamics."""
        name = self.scene.name
        if self.load is None:
            raise ConfigError(
                f"scene={name} is periodic: give its macroscopic load, load=<one of "
                f"{list(LOAD_KINDS)}> (conf/load/; load.strain=..., load.steps=...)"
            )
        if self.actuation:
            raise ConfigError(
                f"actuation={self.actuation}: scene={name} is periodic, with no actuated groups; "
                "its load is F_bar (load=...)"
            )
        if self.dynamics.enabled:
            raise ConfigError(
                f"dynamics.scheme={self.dynamics.scheme}: scene={name} is periodic, and its load "
                "path is static (a sequence of equilibria); leave dynamics off"
            )
        from .material_model import material_model

        # the settings' defaults, and what solver=auto fills in for this material
        default = {**vars(SolverConfig()), **material_model(self.material.nu).solver}
        given = [
            f"solver.{f}={getattr(self.solver, f)}"
            for f in self.solver.__dataclass_fields__
            if getattr(self.solver, f) not in (getattr(SolverConfig(), f), default.get(f))
        ]
        if given:
            raise ConfigError(
                f"{', '.join(given)}: scene={name} is periodic, and its load path is solved by "
                "nma.periodic's own Newton, which takes no solver settings; leave them out"
            )


@dataclass
class ExportConfig(Schema):
    """`python -m nma.export run=<run dir>`: a trained run's geometry as a file to make it from."""

    # a training run directory (its .hydra/config.yaml and checkpoints)
    run: str = MISSING
    format: Optional[str] = field(
        default=None, metadata={"doc": "svg, dxf or stl; null: output's extension, else svg"}
    )
    scale: Optional[float] = bounded(
        None,
        "[0.001, 10000]",
        doc="millimetres per length unit of the scene (a part "
        "from microns to metres; the geometry libraries round below that); null: the "
        "run's part.scale, else 1",
    )
    thickness: Optional[float] = bounded(
        None,
        "[0.001, 100000]",
        doc="STL: extrusion height in millimetres; null: the run's part.thickness, else 10",
    )
    samples: int = bounded(
        32,
        "[2, 1024]",
        doc="points per knot span where curves become polylines (STL, the fabrication report)",
    )
    # the file to write; default <run>/export/design.<format>
    output: Optional[str] = None
    # report whether every deformed state of the task's evaluation set is physical
    states: bool = True
    # translation: the paper's Fig. 5 load cases, deformed over the part
    load_cases: bool = False
    load_fraction: float = bounded(
        0.5, "(0, 1]", doc="load_cases: the actuation as a fraction of the task's d_max"
    )
    # material=<name>: the load cases in it (the part as made); null: the run's
    material: Optional[MaterialConfig] = None

    FORMATS: ClassVar[tuple[str, ...]] = ("svg", "dxf", "stl")

    def check(self):
        if self.material is not None and not self.load_cases:
            self.fail(
                "material",
                "chooses the material the load cases are solved in: give load_cases=true too",
            )
        given = self.format
        if given is not None and given not in self.FORMATS:
            self.fail("format", f"must be one of {list(self.FORMATS)}", given)
        if self.output is not None:
            if os.path.isdir(self.output):
                self.fail(
                    "output",
                    f"is a directory; name the file to write (e.g. "
                    f"{os.path.join(self.output, 'design.' + (given or 'svg'))})",
                    self.output,
                )
            if os.path.lexists(self.output):  # nma.export never replaces a file
                self.fail(
                    "output",
                    "names a file that exists; name another (or move it aside)",
                    self.output,
                )
            parent = os.path.dirname(os.path.abspath(self.output))
            while parent and not os.path.exists(parent):
                parent = os.path.dirname(parent)
            if not os.path.isdir(parent):
                self.fail(
                    "output", f"lies below {parent}, which is a file, not a directory", self.output
                )
            suffix = (
                self.output.rpartition(".")[2].lower()
                if "." in self.output.rpartition("/")[2]
                else ""
            )
            if suffix in self.FORMATS and given not in (None, suffix):
                self.fail(
                    "format",
                    f"is {given} but output={self.output} names a .{suffix} file; give one of "
                    "them, or both agreeing",
                )
            if given is None and suffix not in self.FORMATS:
                self.fail(
                    "output",
                    f"needs format= (one of {list(self.FORMATS)}): its extension names none of "
                    "them",
                    self.output,
                )
            self.format = given or suffix
        else:
            self.format = given or "svg"


@dataclass
class EvaluateConfig(Schema):
    """`python -m nma.evaluate run=<run dir> fidelity=<preset>`: a trained run re-evaluated at
    another discretisation (and solver), side by side with its training fidelity."""

    run: str = MISSING
    fidelity: Fidelity = field(default_factory=Fidelity)
    # solver=<backend> (and solver.*): evaluate with it; null: as the run trained
    solver: Optional[SolverConfig] = None
    # contact=on|off: evaluate with or without it; null: as the run trained
    contact: Optional[ContactConfig] = None
    eval_subset: Optional[int] = bounded(
        None,
        "[1, 100000000]",
        doc="this many samples of the task's evaluation "
        "set, evenly spaced through it (as trainer.eval_subset picks them), at "
        "both fidelities: for a set too large to solve finely; null: all of it",
    )


# Neo-Hookean is Mooney-Rivlin with C01 = 0
# a fit reads incompressible tensile data: the laws with the volume term, whose limit that is
FIT_LAWS = tuple(law for law in LAW_NAMES if law != "neo_hookean" and LAWS.get(law).volume_term)


@dataclass
class FitConfig(Schema):
    """`python -m nma.fit data=<csv> law=<law> output=<yaml>`: a hyperelastic law fitted to
    stress-strain data."""

    # a CSV of engineering strain and nominal stress (nma.fit reads its header)
    data: str = MISSING
    law: str = choice("yeoh", FIT_LAWS, doc="the law fitted (nma.mechanics.laws)")
    terms: int = bounded(2, "[1, 3]", doc="ogden: its number of terms")
    mode: str = choice("uniaxial", MODES, doc="the test, where the data has no `mode` column")
    strain_column: str = option(
        "strain",
        "the engineering strain's column (the Soft Robotics Materials Database's: "
        "'Engineering Strain')",
    )
    stress_column: str = option(
        "stress", "the nominal stress's column (force over the undeformed section)"
    )
    max_strain: Optional[float] = bounded(
        None,
        "(0, 100]",
        doc="fit the data up to this engineering strain (in magnitude); null: all of it",
    )
    nu: float = bounded(
        0.499,
        MATERIAL_RANGES["nu"],
        doc="the material's Poisson's ratio (volume change), which "
        "a tensile test does not measure; elastomers are nearly incompressible",
    )
    unit: str = choice("MPa", STRESS_UNITS, doc="the stress column's unit")
    starts: int = bounded(
        8,
        "[1, 100]",
        doc="initial guesses tried (the best fit is kept): Ogden's fits have many local minima",
    )
    name: Optional[str] = None  # the material, in words (written to the file)
    source: Optional[str] = None  # where the data comes from (written to the file)
    # the material file to write (conf/material/<name>.yaml); null: print only
    output: Optional[str] = None

    def check(self):
        check_fit(self)
        if not os.path.isfile(self.data):
            self.fail("data", "must name a CSV file", self.data)
        if self.output is not None and os.path.lexists(self.output):
            self.fail(
                "output", "names a file that exists; name another (or move it aside)", self.output
            )
