"""How nma sets JAX up (nma.runtime.configure_jax, which conftest calls as every command does)."""

from __future__ import annotations

import threading

import jax
import jax.numpy as jnp
import numpy as np


def test_a_host_callback_behind_a_pending_program_runs_on_the_callers_thread():
    # With the CPU client's async dispatch, a callback program whose input is still being
    # computed runs later on one of XLA's threads; when that callback calls compiled kernels
    # (as every host solve does) while the caller goes on with its own, the two can wait on each
    # other for ever.  configure_jax runs each program on its caller's thread, so the callback
    # has run when the call returns.
    ran_on = []

    def host(x):
        ran_on.append(threading.current_thread())
        return np.asarray(jnp.sum(jnp.asarray(x)) + jnp.zeros(x.shape))

    pending = jax.jit(lambda a: (a @ a @ a)[0])(jnp.ones((1500, 1500)))
    out = jax.pure_callback(host, jax.ShapeDtypeStruct(pending.shape, pending.dtype), pending)
    assert ran_on == [threading.current_thread()]
    assert float(out[0]) == 1500.0**3
