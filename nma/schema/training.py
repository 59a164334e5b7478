"""Training: the encoder, the optimiser, the trainer's schedule and checkpoints, the logger."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, List, Optional

from ..settings import Schema, bounded, choice


@dataclass
class ModelConfig(Schema):
    """Encoder: MLP with ReLU hidden layers, output d_max * tanh (authors' code: no last bias)."""

    prefix: ClassVar[str] = "model"
    name: str = "mlp"  # an encoder registered in nma.models
    hidden: Optional[List[int]] = bounded(
        None, "[1, 100000]", doc="null: the task's widths (task.hidden)"
    )
    out_bias: bool = False  # a bias on the output layer (the authors' code has none)


@dataclass
class LrScale(Schema):
    """Learning rate of each geometry group as a multiple of the network's; 0 freezes the group."""

    prefix: ClassVar[str] = "optim.lr_scale"
    radii: float = bounded(1.0, "[0, inf)", doc="the cells' pore radii")
    corners: float = bounded(1.0, "[0, inf)", doc="the cell corners' moves")
    pore_radii: float = bounded(1.0, "[0, inf)", doc="shape matching's central pore radii")
    colours: float = bounded(1.0, "[0, inf)", doc="digital MNIST's colour field")


@dataclass
class OptimConfig(Schema):
    """Adam per parameter group, optionally with cosine decay to final_fraction * lr."""

    prefix: ClassVar[str] = "optim"
    name: str = choice("adam", ("adam",), doc="Adam (optax), per parameter group")
    lr: float = bounded(
        1e-3, "(0, inf)", doc="the network's learning rate (each task brings its own: conf/optim/)"
    )
    lr_scale: LrScale = field(default_factory=LrScale)
    schedule: str = choice(
        "constant",
        ("constant", "cosine"),
        doc="cosine: decays to final_fraction x lr over trainer.steps",
    )
    final_fraction: float = bounded(
        0.1, "[0, 1]", doc="the cosine schedule's last rate, a fraction of lr"
    )


@dataclass
class TrainerConfig(Schema):
    prefix: ClassVar[str] = "trainer"
    steps: int = bounded(100, "[1, 10000000]", doc="training steps, one batch each")
    batch_size: int = bounded(
        8, "[1, 100000]", doc="task samples a step (a multiple of the MPI ranks)"
    )
    eval_every: int = bounded(
        25, "[1, 10000000]", doc="steps between evaluations (and the last step's)"
    )
    eval_subset: Optional[int] = bounded(
        200,
        "[1, 100000000]",
        doc="evaluations before the last use this many "
        "samples of the evaluation set, evenly spaced through it (the same ones "
        "every time); the last evaluation, the run's metric, uses all; null: all",
    )
    checkpoint_every: int = bounded(
        25, "[1, 10000000]", doc="steps between checkpoints (and the last step's)"
    )
    resume: Any = field(
        default="false", metadata={"doc": "false | true | force (ignore a changed config)"}
    )
    # the paper's baseline: control only, the initial design stays
    freeze_geometry: bool = False
    seed: int = bounded(
        0, "[0, 4294967295]", doc="the network's initialisation and the batches' samples"
    )
    fields: str = choice(
        "final",
        ("final", "all", "none"),
        doc="HDF5 fields of the evaluation samples: of the final evaluation, of every one, or none",
    )
    fields_samples: int = bounded(
        9, "[2, 64]", doc="material points per patch side in the HDF5 fields"
    )
    animation_frames: int = bounded(
        24,
        "[0, 1000]",
        doc="frames of figures/sweep.gif, the material as the task's "
        "descriptor sweeps its range; 0: none",
    )
    max_nonfinite_steps: int = bounded(
        3, "[1, 1000]", doc="consecutive skipped (non-finite) updates before stopping"
    )
    stop_grace: float = bounded(
        60.0,
        "(0, 86400]",
        doc="seconds a SIGTERM or Ctrl-C waits for the current step to "
        "finish and be checkpointed before the run stops without it",
    )
    max_failed_steps: int = bounded(
        5,
        "[1, 1000]",
        doc="consecutive steps in which no sample of the batch converged "
        "(each skipped: nothing to learn from) before stopping",
    )
    inversion_penalty: float = bounded(
        0.1,
        "[0, inf)",
        doc="weight of a loss term that steers the design away "
        "from states that invert between Gauss points: the sum over every element's "
        "4 x 4 check points of max(0, inversion_margin - det F)^2 (nma.mechanics.energy, "
        "inversion_penalty); 0: off (the paper's objective alone). Tasks that solve "
        "nothing (the MNIST fit) have no states for it",
    )
    inversion_margin: float = bounded(
        0.2, "(0, 1)", doc="det F below which the inversion penalty acts"
    )
    min_feature: Optional[float] = bounded(
        None,
        "(0, 10000]",
        doc="the narrowest ligament (material between two "
        "boundary curves) the design may have, in millimetres at part.scale, "
        "which it needs; enforced by the feature penalty "
        "(nma.geometry.features); one wider than any design "
        "of the scene can have is refused (nma.schema.effect); "
        "null: no bound (the width is still reported)",
    )
    feature_penalty: float = bounded(
        10.0,
        "[0, inf)",
        doc="with min_feature: weight of a loss term, the sum over "
        "pairs of boundary curves of (max(0, min_feature - width) / min_feature)^2 "
        "(unitless: the same in any scene units); 0: the bound is reported, not enforced",
    )
    # a run directory: start from its geometry (and network, where it fits)
    init_from: Optional[str] = None
    progress: bool = True  # a progress bar with the time left

    def check(self):
        self.resume = str(self.resume).lower()  # Hydra parses `trainer.resume=true` as a bool
        if self.resume not in ("false", "true", "force"):
            self.fail("resume", "must be one of ['false', 'true', 'force']", self.resume)


@dataclass
class LoggerConfig(Schema):
    prefix: ClassVar[str] = "logger"
    name: str = choice(
        "wandb",
        ("wandb", "none"),
        doc="wandb: Weights & Biases, offline unless WANDB_MODE says otherwise",
    )
    mode: str = choice("offline", ("offline", "online", "disabled"), doc="offline needs no network")
    project: str = "nma"  # the Weights & Biases project
