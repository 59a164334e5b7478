"""SpecTask: the schema of a task posed in YAML (nma.tasks.spec), with the goals it can set."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Dict, List, Optional

from ..errors import ConfigError
from ..settings import bounded, choice
from .task_config import TaskConfig


GOALS = {  # goal -> (tracked points it needs: None any number, 0 none; the descriptor's dimension)
    "move": (None, 2),  # every point to its rest position + t
    "rotate": (2, 1),  # the two points about their rest midpoint by t radians
    "distance": (2, 1),  # the two points' distance to its rest value + t
    "pore_area": (0, 1),  # the area inside the pore of cell `pore` to its rest area x (1 + t)
    "force": (0, 1),  # the force the actuation of group `group` pushes with (dW/dd) to t
}


@dataclass
class SpecTask(TaskConfig):
    """A task posed in YAML (nma.tasks.spec): what it observes (tracked points, or a pore's
    boundary), the goal it sets them as a function of the descriptor t, and where t comes from: a
    box (uniform in training; a grid of eval_points per dimension in evaluation), named cases, or a
    dataset file (each drawn with equal chance in training, all of them in evaluation).  `name` is
    the scene's."""

    points: List[str] = field(default_factory=list)  # tracked points of the scene, in order
    goal: str = choice(
        "move",
        tuple(GOALS),
        doc="move: each point to rest + t (t in 2D); rotate: two points "
        "about their midpoint by t radians; distance: two points' distance to rest + t; "
        "pore_area: the pore of cell `pore` to its rest area x (1 + t); force: the force the "
        "actuation of group `group` pushes with (the strain energy's derivative) to t",
    )
    # pore_area: the porous cell [column, row], from the bottom left, 0-based
    pore: Optional[List[int]] = None
    group: Optional[str] = None  # force: an actuated group of the scene (scene.groups)
    low: Optional[List[float]] = None  # a box: low[i] <= t[i] <= high[i]
    high: Optional[List[float]] = None
    cases: Dict[str, List[float]] = field(default_factory=dict)  # or named descriptors, {name: t}
    # or a CSV file of descriptors, one per row (nma.tasks.spec.descriptors)
    dataset: Optional[str] = None
    eval_points: int = bounded(
        5, "[1, 1000]", doc="evaluation of a box: descriptors per dimension, evenly over it"
    )
    loss: str = choice(
        "l1",
        ("l1", "l2"),
        doc="per sample: mean absolute (l1) or squared (l2) error of the "
        "observed points (move, rotate), of the distance, of the area ratio or of the force",
    )

    @property
    def factory(self) -> str:
        return "spec"

    @property
    def dim(self) -> int:
        """The descriptor's dimension."""
        return GOALS[self.goal][1]

    def check(self):
        need, dim = GOALS[self.goal]
        if len(set(self.points)) != len(self.points) or (need != 0 and not self.points):
            self.fail("points", "must name one or more distinct tracked points", self.points)
        if need is not None and len(self.points) != need:
            self.fail(
                "points",
                f"must name {need} tracked points for goal {self.goal}"
                if need
                else f"must be empty for goal {self.goal}, which observes "
                + ("a pore (task.pore)" if self.goal == "pore_area" else "a group (task.group)"),
                self.points,
            )
        if (self.goal == "pore_area") != (self.pore is not None):
            self.fail(
                "pore",
                "must name a porous cell [column, row] for goal pore_area, and only for it",
                self.pore,
            )
        if (self.goal == "force") != (self.group is not None):
            self.fail(
                "group",
                "must name an actuated group of the scene for goal force, and only for it",
                self.group,
            )
        if self.pore is not None and (len(self.pore) != 2 or min(self.pore) < 0):
            self.fail(
                "pore", "must be a cell [column, row], counted from 0 at the bottom left", self.pore
            )
        if (self.low is None) != (self.high is None):
            self.fail(
                "low" if self.low is None else "high",
                "must be given with task."
                f"{'high' if self.low is None else 'low'}: together they are the descriptors' box",
            )
        given = [
            k for k, v in (("low", self.low), ("cases", self.cases), ("dataset", self.dataset)) if v
        ]
        if len(given) != 1:
            self.fail(
                "low",
                "and task.high (a box), task.cases or task.dataset: give exactly one of them, got "
                f"{given + (['high'] if self.high else []) or 'none'}",
            )
        for name, t in (
            [("low", self.low), ("high", self.high)]
            if self.low is not None
            else [(f"cases.{k}", v) for k, v in self.cases.items()]
        ):
            if len(t) != dim:
                self.fail(
                    name,
                    f"must have {dim} value{'s' if dim > 1 else ''} for goal {self.goal} "
                    f"(the descriptor's dimension)",
                    t,
                )
            self.check_values(name, t)
        if self.low is not None and not all(lo < hi for lo, hi in zip(self.low, self.high)):
            self.fail("high", f"must exceed task.low {self.low} in every entry", self.high)
        if self.dataset and not os.path.isfile(self.dataset):
            relative = (
                ""
                if os.path.isabs(self.dataset)
                else f", read from the current directory {os.getcwd()}"
            )
            self.fail("dataset", f"{self.dataset} cannot be read: it is not a file{relative}")

    def check_values(self, name: str, t) -> None:
        """A descriptor the goal can meet: angles within [-pi, pi], an area that stays positive."""
        if self.goal == "rotate" and not all(
            -3.141592653589793 <= v <= 3.141592653589793 for v in t
        ):
            self.fail(name, "holds angles in radians, within [-pi, pi], for goal rotate", t)
        if self.goal == "pore_area" and not all(v > -1 for v in t):
            self.fail(
                name,
                "holds relative changes of the pore's area, each above -1 (no area left) for goal "
                "pore_area",
                t,
            )

    def check_scene(self, scene) -> None:
        """The points must be tracked by the scene (a SceneConfig), the pore one of its porous
        cells, the group one of its actuated groups."""
        missing = [p for p in self.points if p not in scene.tracked]
        if missing:
            raise ConfigError(
                f"task.points names {missing}, which scene {scene.name} does not track; its "
                f"tracked points are {sorted(scene.tracked)} (scene.tracked)"
            )
        if self.goal in ("distance", "rotate") and len(self.points) == 2:
            a, b = (scene.tracked[p] for p in self.points)
            # no distance, no direction between them
            if [float(v) for v in a] == [float(v) for v in b]:
                raise ConfigError(
                    f"task.points {self.points} are one place in scene {scene.name} ({list(a)}): "
                    f"goal {self.goal} needs two points apart"
                )
            apart = math.dist([float(v) for v in a], [float(v) for v in b])
            asked = (
                [v[0] for v in self.cases.values()]
                if self.cases
                else [self.low[0]]
                if self.low and not self.dataset
                else []
            )
            # a dataset's rows: when it is read
            if self.goal == "distance" and asked and apart + min(asked) <= 0:
                raise ConfigError(
                    f"task.{'cases' if self.cases else 'low'} asks for a distance change of "
                    f"{min(asked):g}, but {', '.join(self.points)} are {apart:g} apart at rest: "
                    f"each change must be above {-apart:g}"
                )
        if self.group is not None and self.group not in [g.name for g in scene.groups]:
            raise ConfigError(
                f"task.group {self.group!r} is not an actuated group of scene {scene.name}; its "
                f"groups are {[g.name for g in scene.groups]} (scene.groups)"
            )
        if self.pore is not None:
            rows = scene.rows()[::-1]  # bottom row first
            i, j = self.pore
            if not (j < len(rows) and i < len(rows[j]) and rows[j][i] == "P"):
                raise ConfigError(
                    f"task.pore {self.pore} is not a porous cell of scene {scene.name} (a grid of "
                    f"{len(rows[0])} columns and {len(rows)} rows, counted from 0 at the bottom "
                    f"left; the porous cells are P in scene.cells), got {self.pore}"
                )
