"""Natural frequencies and when the static model suffices.

The small vibrations about a state solve K_ff phi = omega^2 M_ff phi (free dofs; the prescribed ones
held), with K the tangent and M the consistent mass at the same discretisation.  The lowest few come
from scipy's Lanczos in shift-invert mode about 0 (eigsh, sigma = 0; K_ff is positive definite at a
stable state).

When dynamics matters: a structure driven by an actuation whose fastest content has period T_a lags
its static equilibrium by about (T_1 / T_a)^2 of the motion, T_1 = 2 pi / omega_1 its lowest natural
period (the quasi-static response of an oscillator below resonance: the dynamic amplification is
1 / (1 - (omega / omega_1)^2)).  Below QUASI_STATIC (1%) the static model gives the same answer.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import scipy.sparse.linalg as spla
from scipy.sparse.linalg import ArpackError

from .. import checks
from ..errors import SolverError
from ..mechanics.energy import Tangents, quadrature
from ..solver.equations import tangents_at
from .mass import mass_blocks

QUASI_STATIC = 0.01  # the relative dynamic amplification below which the static model suffices


def natural_frequencies(
    sim, X, mat, density: float = 1.0, count: int = 6, d=None, u_free=None
) -> np.ndarray:
    """The lowest `count` angular frequencies omega (rad per unit time) of small vibrations about
    the state (d, u_free) (rest where None), ascending (arguments as natural_modes')."""
    return _modes("natural_frequencies", sim, X, mat, density, count, d, u_free)[0]


def natural_modes(sim, X, mat, density: float = 1.0, count: int = 6, d=None, u_free=None):
    """(omega (count,), modes (count, free dofs) M-orthonormal): the lowest natural frequencies and
    their mode shapes about the state (d, u_free) (rest where None).  X (n_points, 2), mat (the
    material's parameters), d (n_actuations,) and u_free (free dofs,) are checked as
    Simulator.equilibrium's, density is positive, and count lies in [1, free dofs - 2] (what Lanczos
    can find)."""
    return _modes("natural_modes", sim, X, mat, density, count, d, u_free)


def _modes(where, sim, X, mat, density, count, d, u_free):
    X, mat, density, count, d, u_free = _checked(where, sim, X, mat, density, count, d, u_free)
    eqs, pattern = sim.equations, sim.backend.pattern
    d = jnp.zeros(sim.n_actuations) if d is None else jnp.asarray(d)
    u_free = jnp.zeros(sim.disc.boundary.n_dofs) if u_free is None else jnp.asarray(u_free)
    kel = tangents_at(eqs, X, d, mat, u_free)
    M = mass_blocks(eqs.solid, quadrature(eqs.solid, X), density)
    none = jnp.zeros((0, 18, 18))
    K_ff = _full(pattern.matrix(kel))
    M_ff = _full(pattern.matrix(Tangents(M, none, jnp.zeros(0, int), jnp.asarray(0))))
    count = min(count, K_ff.shape[0] - 2)
    # a fixed start vector: ARPACK's own is random, and the time step taken from these would
    # differ at round-off from one run to the next
    start = np.random.default_rng(0).uniform(-1.0, 1.0, K_ff.shape[0])
    w2, modes = spla.eigsh(K_ff, k=count, M=M_ff, sigma=0.0, which="LM", v0=start)
    order = np.argsort(w2)
    return np.sqrt(np.clip(w2[order], 0.0, None)), modes[:, order].T


class ModalFailure(Exception):
    """The modal solve (ARPACK, shift-invert about 0) failed: a tangent singular or nearly so."""


def solved(sim, X, mat, density, count, d=None, u_free=None) -> np.ndarray:
    """natural_frequencies, its own failures (ARPACK's, SuperLU's singular tangent) raised as
    ModalFailure with the reason."""
    try:
        return natural_frequencies(sim, jnp.asarray(X), mat, density, count, d, u_free)
    except ArpackError as err:  # ArpackNoConvergence too
        raise ModalFailure(f"{type(err).__name__}: {err}") from None
    except RuntimeError as err:
        if type(err) is not RuntimeError:  # JAX's, a solver's: not the modal solve's own
            raise
        raise ModalFailure(str(err)) from None  # SuperLU: a singular tangent


def lowest_at_rest(sim, X, mat, density) -> float:
    """The lowest natural frequency at rest; SolverError where the modal solve fails or finds 0 (a
    mechanism: no period to step by)."""
    try:
        omega = float(solved(sim, X, mat, density, 1)[0])
    except ModalFailure as err:
        raise SolverError(
            f"dynamics: the lowest natural frequency at rest could not be computed "
            f"({err}); it sets dynamics.dt and dynamics.ramp where they are null"
        ) from None
    if not omega > 0:
        raise SolverError(
            "dynamics: the lowest natural frequency at rest is 0 (a mechanism: the "
            "tangent is singular there); give dynamics.dt and dynamics.ramp"
        )
    return omega


def _checked(where, sim, X, mat, density, count, d, u_free):
    """natural_modes' arguments, refused in one line naming `where` and the argument."""
    from .checks import ranges

    free = sim.disc.boundary.n_dofs

    def array(name, value, shape):
        return checks.array(where, name, value, shape, float64=True).astype(jnp.float64)

    X = array("X", X, (sim.disc.mesh.n_points, 2))
    mat = array("mat", mat, (sim.disc.material.n_params,))
    sim.disc.material.check(np.asarray(mat), where)
    density = checks.number(where, "density", density, ranges()["density"])
    count = checks.integer(where, "count", count, f"[1, {free - 2}]")
    if d is not None:
        d = array("d", d, (sim.n_actuations,))
    if u_free is not None:
        u_free = array("u_free", u_free, (free,))
    return X, mat, density, count, d, u_free


def _full(A):
    """A symmetric matrix from a pattern that may hold its upper triangle only (PARDISO's)."""
    import scipy.sparse as sp

    upper = sp.triu(A)
    upper_only = (A != A.T).nnz and sp.tril(A, -1).nnz == 0
    return (upper + sp.triu(A, 1).T).tocsc() if upper_only else A.tocsc()


def dynamic_amplification(omega_1: float, period: float) -> float:
    """How far a response lags the static one at an actuation of the given period:
    (T_1/T)^2 / (1 - (T_1/T)^2) (infinite at and past resonance).  omega_1 and period are
    positive."""
    omega_1 = checks.number("dynamic_amplification", "omega_1", omega_1, "(0, inf)")
    period = checks.number("dynamic_amplification", "period", period, "(0, inf)")
    r2 = (2.0 * np.pi / omega_1 / period) ** 2
    return float(r2 / (1.0 - r2)) if r2 < 1.0 else float("inf")


def static_suffices(omega_1: float, period: float) -> str | None:
    """The message that the static model gives the same answer, where the actuation's shortest
    period is slow next to the lowest natural period; None where dynamics matters."""
    omega_1 = checks.number("static_suffices", "omega_1", omega_1, "(0, inf)")
    period = checks.number("static_suffices", "period", period, "(0, inf)")
    amp = dynamic_amplification(omega_1, period)
    if amp >= QUASI_STATIC:
        return None
    return (
        f"the actuation's shortest period {period:.4g} is "
        f"{period * omega_1 / (2 * np.pi):.3g} times the structure's lowest natural period "
        f"{2 * np.pi / omega_1:.4g}: the static model gives the same answer within "
        f"{100 * amp:.2g}% (dynamics=off)"
    )
