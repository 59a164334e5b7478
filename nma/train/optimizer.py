"""The optimiser of a training run, and what a run that keeps failing its solves should change."""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax
import numpy as np
import optax

from ..solver.status import Status

if TYPE_CHECKING:
    from ..schema import OptimConfig


# What to change when the batches' solves keep failing, by the first failed sample's status
FAILED_STEP_ADVICE = {
    Status.INVERTS: (
        "The actuations ask for states that invert the material between Gauss points: "
        "trainer.inversion_penalty "
        "steers the design away from them, a smaller actuation range (the task's d_max) or a finer "
        "fidelity (fidelity.ctrl_per_patch) gives the solve room"
    ),
    None: (
        "Give Newton more room (solver.max_iters, solver.max_step_iters, "
        "solver.corrector=trust_region), "
        "or ask less of the design (the task's d_max, a lower optim.lr)"
    ),
}


def make_optimizer(
    ocfg: OptimConfig,
    geometry_keys,
    freeze_geometry: bool,
    steps: int,
    max_nonfinite: int,
    frozen: tuple[str, ...] = (),
):
    """Adam per parameter group; a frozen group (scale 0 or the geometry-frozen baseline) gets no
    update. An update whose gradients are not finite is skipped (optax.apply_if_finite counts
    them)."""

    def lr(scale):
        if ocfg.schedule == "cosine":
            return optax.cosine_decay_schedule(ocfg.lr * scale, steps, alpha=ocfg.final_fraction)
        return ocfg.lr * scale

    transforms = {"network": optax.adam(lr(1.0))}
    for k in geometry_keys:
        scale = 0.0 if freeze_geometry or k in frozen else float(getattr(ocfg.lr_scale, k))
        transforms[k] = optax.adam(lr(scale)) if scale > 0 else optax.set_to_zero()
    labels = {"net": "network", "geom": {k: k for k in geometry_keys}}
    return optax.apply_if_finite(optax.multi_transform(transforms, labels), max_nonfinite)


def nonfinite_groups(tree) -> list[str]:
    """The parameter groups (network, each geometry group) of a tree that hold a value that is not
    finite."""
    groups = {"network": tree["net"], **tree["geom"]}
    return [
        k
        for k, v in groups.items()
        if not all(np.all(np.isfinite(np.asarray(a))) for a in jax.tree_util.tree_leaves(v))
    ]


def diagnose(params, ocfg: "OptimConfig", step: int, what: str) -> str:
    """Name the likely cause of non-finite training: which parameters blew up, at what rates."""
    size = {"network": params["net"], **params["geom"]}
    largest = {
        k: max(
            (float(np.max(np.abs(np.asarray(a)))) for a in jax.tree_util.tree_leaves(v)),
            default=0.0,
        )
        for k, v in size.items()
    }
    big = [
        f"{k} (max |value| {v:.3g})" for k, v in largest.items() if not np.isfinite(v) or v > 1e6
    ]
    rates = f"optim.lr = {ocfg.lr:g}" + "".join(
        f", optim.lr_scale.{k} = {getattr(ocfg.lr_scale, k):g}" for k in params["geom"]
    )
    cause = (
        f"parameters that diverged: {', '.join(big)}; the likely cause is a learning rate far too "
        "large"
        if big
        else "no parameter group diverged; the likely cause is the task's loss at these "
        "parameters or a learning rate too large"
    )
    return f"step {step}: {what}. {cause} ({rates}). Lower optim.lr and start a new run."
