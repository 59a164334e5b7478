"""Leaving saddles (solver.escape_saddles, PARDISO: its LDL^T factorisation reports inertia): each
converged load step and the final state are checked for negative eigenvalues; a saddle is left along
its most unstable mode (nma.solver.newton.leave_saddle) and Newton goes on to a stable
equilibrium."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

MAX_SADDLE_CHECKS = 16  # converged load steps checked for stability per solve
# bisections (in log shift) bracketing a saddle's lowest eigenvalue to a factor 10^(1/64)
SHIFT_BISECTIONS = 6
INVERSE_ITERATIONS = 10  # block inverse iterations for a saddle's most unstable modes
# modes sought at once (the lowest eigenvalues of a symmetric structure come in near pairs)
SADDLE_BLOCK = 4


def leave(newton, p, lin, ws):
    """Find the most unstable mode of a saddle (a HostNewton's linearised state `lin`, workspace
    `ws`) and step along it.  Soft stable modes of thin walls can lie nearer zero than the unstable
    ones, so the search is shifted: the inertia of K + sigma I counts the eigenvalues below -sigma,
    and bisection on it (in log sigma) brackets the lowest eigenvalue, -sigma_hi < lambda_min <=
    -sigma_lo; inverse iteration with the (positive definite) factor of K + sigma_hi I then
    amplifies the lowest modes most, and Rayleigh-Ritz on a block of them gives the direction of
    most negative curvature.  The linearised state there, or None if the energy does not fall along
    it."""
    with newton.backend.clock.time("saddles"):
        kel = jax.device_get(lin.kel)
        unstable = lambda sigma: ws.factorise(kel, sigma) or newton.backend.inertia(ws)
        lo, hi = 0.0, 1e-9 * float(lin.state.k_ref)
        while unstable(hi):
            lo, hi = hi, 10.0 * hi
            if hi > float(lin.state.k_ref):
                return None
        for _ in range(SHIFT_BISECTIONS):
            mid = np.sqrt(lo * hi) if lo > 0 else 0.1 * hi
            lo, hi = (mid, hi) if unstable(mid) else (lo, mid)
        if not (lo > 0 or unstable(0.0)):
            return None
        ws.factorise(kel, hi)
        A = newton.backend.pattern.matrix(kel)
        V = np.random.default_rng(0).standard_normal((A.shape[0], SADDLE_BLOCK))  # reproducible
        for _ in range(INVERSE_ITERATIONS):
            V = np.linalg.qr(ws.solve(V))[0]
        KV = np.column_stack([newton.backend.matvec(A, V[:, j]) for j in range(SADDLE_BLOCK)])
        theta, Y = np.linalg.eigh(0.5 * (V.T @ KV + KV.T @ V))
        v, curvature = V @ Y[:, 0], float(theta[0])
        if not curvature < 0:
            return None
        left, ok = newton.linearised(
            lambda k: k.leave(p, lin, jnp.asarray(v), curvature),
            lin.kel.which.shape[-1],
            lambda out: out[0].kel,
        )
        if not bool(ok):
            return None
        newton.backend.count("saddles_left")
        return left
