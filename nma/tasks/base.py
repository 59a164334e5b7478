"""The small protocol through which the trainer knows a task.

A task samples descriptors t, turns them into network inputs, reads its outputs off an equilibrium
(`observe`), scores them (`loss`, differentiable, per sample) and reports a metric a reader
understands on a fixed evaluation set.  It knows the simulator only through `observe`.
"""
from __future__ import annotations

import jax.numpy as jnp


class Task:
    name: str
    d_max: float
    metric_name: str
    metric_unit: str

    def sample(self, key, n: int) -> jnp.ndarray:  # (n, k) descriptors
        raise NotImplementedError

    def net_input(self, t: jnp.ndarray) -> jnp.ndarray:
        return t

    def observe(self, sim, X, u) -> jnp.ndarray:
        raise NotImplementedError

    def targets(self, t: jnp.ndarray) -> jnp.ndarray:  # what observe should equal, same shape
        raise NotImplementedError

    def loss(self, out: jnp.ndarray, t: jnp.ndarray) -> jnp.ndarray:
        """L1 distance of the observed points to their targets (REFERENCE.md; the paper says MSE)."""
        return jnp.mean(jnp.abs(out - self.targets(t)))

    def metric(self, out: jnp.ndarray, t: jnp.ndarray) -> jnp.ndarray:
        raise NotImplementedError

    def eval_set(self) -> jnp.ndarray:
        raise NotImplementedError


def check_range(name: str, value: float, lo: float, hi: float) -> float:
    if not lo <= value <= hi:
        raise ValueError(f"{name} must be in [{lo}, {hi}], got {value}")
    return float(value)
