"""Encoders: task descriptor -> actuations, bounded by d_max * tanh."""

from __future__ import annotations

from typing import Sequence

import flax.linen as nn
import jax.numpy as jnp

from ..registry import MODELS


class Encoder(nn.Module):
    """MLP with ReLU hidden layers; the output layer has no bias (authors' code) and is
    tanh-scaled."""

    hidden: Sequence[int]
    n_out: int
    d_max: float
    out_bias: bool = False
    dtype: jnp.dtype = jnp.float64

    @nn.compact
    def __call__(self, t):
        h = t
        for width in self.hidden:
            h = nn.relu(nn.Dense(width, dtype=self.dtype, param_dtype=self.dtype)(h))
        out = nn.Dense(
            self.n_out, use_bias=self.out_bias, dtype=self.dtype, param_dtype=self.dtype
        )(h)
        return self.d_max * jnp.tanh(out)


@MODELS.register("mlp")
def mlp(hidden: Sequence[int], n_out: int, d_max: float, out_bias: bool = False) -> Encoder:
    return Encoder(tuple(int(w) for w in hidden), int(n_out), float(d_max), bool(out_bias))
