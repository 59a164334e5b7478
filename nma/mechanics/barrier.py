"""The barrier of incremental potential contact (Li et al. 2020, Eq. 6), in the unit variable s:

    b(s) = -(s - 1)^2 log s   for 0 < s < 1,   0 for s >= 1,

C2 at s = 1 and infinite at s = 0.  Both barriers of the model use it: on det F / J_hat (the
inversion barrier, nma.mechanics.energy) and on squared distance / d_hat^2 (contact,
nma.mechanics.contact).
"""

from __future__ import annotations

import jax.numpy as jnp


def ipc(s):
    """b, b', b'' at s (elementwise; 0 at and above 1).  s > 0 is the caller's to keep: at s <= 0
    the values are those at s = 1."""
    inside = s < 1.0
    s = jnp.where(inside & (s > 0), s, 1.0)
    log, q = jnp.log(s), s - 1.0
    values = (-q * q * log, -2.0 * q * log - q * q / s, -2.0 * log - 4.0 * q / s + q * q / (s * s))
    return [jnp.where(inside, v, 0.0) for v in values]
