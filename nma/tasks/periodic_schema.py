"""The settings of the tasks posed on a periodic cell's effective response (nma.periodic.tasks): a
single design trained to a target Poisson's ratio, and a network mapping the target to the cell's
pore shape over a range of targets."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, List

from ..settings import bounded, choice
from .task_config import TaskConfig


@dataclass
class PeriodicPoissonTask(TaskConfig):
    """The effective Poisson's ratio -eps_lateral / eps_axial of a periodic scene's cell (its
    fidelity, contact and material the run's), from its initial design (circular holes of
    scene.porosity), compressed
    under uniaxial nominal stress to task.strain, brought to a target."""

    periodic: ClassVar[bool] = True  # it runs on a periodic scene (nma.periodic)
    name: str = "square_array"  # the periodic scene it runs on
    kind: str = choice(
        "periodic_poisson",
        ("periodic_poisson", "periodic_poisson_amortised"),
        doc="one design to task.target, or a network over task.target_range",
    )
    axis: str = choice("y", ("x", "y"), doc="the compressed axis")
    strain: float = bounded(
        -0.1, "[-0.3, -0.01]", doc="the nominal strain the Poisson's ratio is taken at"
    )
    steps: int = bounded(
        5, "[1, 100]", doc="output points along the load path, each one checked physical"
    )
    target: float = bounded(
        -0.5, "[-1, 1]", doc="the target Poisson's ratio (task periodic_poisson)"
    )
    target_range: List[float] = bounded(
        spec="[-1, 1]",
        factory=lambda: [-0.4, 0.1],
        doc="the targets a network learns (task periodic_poisson_amortised): [low, high]",
    )
    train_targets: int = bounded(
        6,
        "[2, 1000]",
        doc="training targets, evenly over target_range; the evaluation's are the midpoints "
        "between them (held out)",
    )
    d_max: float = bounded(
        0.25, "(0, 1]", doc="the network's pore radii move at most d_max from the initial ones"
    )
    hidden: List[int] = bounded(
        spec="[1, 100000]", factory=lambda: [16, 16], doc="the encoder's hidden widths"
    )

    @property
    def factory(self) -> str:
        return self.kind

    def check(self):
        if len(self.target_range) != 2 or not self.target_range[0] < self.target_range[1]:
            self.fail("target_range", "must be [low, high] with low < high", self.target_range)
