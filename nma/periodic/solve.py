"""Newton on a periodic cell's reduced equations, and a load path followed by load steps.

Each load step moves F_bar's prescribed components by a consistent predictor (the linearised
response to the increment, K dz = -(g + T^T K u_aff), bounded to keep det F > 0 along it), then
corrects at fixed load by Newton with an Armijo line search on the energy, every step bounded to
keep det F > 0 at the Gauss and check points; a direction of negative curvature (an indefinite
Hessian) is replaced by a shifted one.  A load step that does not converge returns to the last
converged state and halves its increment (warm starts, cuts on failure: as the static solver's
actuation steps, nma.solver.loading); quick steps grow the next increment.

With `stability`, every converged state's reduced Hessian is checked: its lowest eigenvalue turning
negative is a bifurcation of the path (a symmetric path past it stands on a saddle).  With `escape`
the state then leaves the saddle along the unstable mode, downhill, and Newton settles on the
buckled branch at the same load: the branch is chosen by the energy's descent along the mode (its
sign fixed so that the mode's largest entry is positive).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .problem import STEP_FRACTION, PeriodicProblem

ARMIJO = 1e-4
NEGATIVE = 1e-9  # an eigenvalue below -NEGATIVE x k_ref is negative


@dataclass
class NewtonSettings:
    rtol: float = 1e-10  # ||D g|| <= rtol x k_ref x L closes a load step (problem.force_norm)
    max_iters: int = 40  # corrector iterations per load step
    max_backtracks: int = 30
    min_increment: float = 1e-4  # of the path parameter: below it a cut ends the path
    grow: float = 1.5


@dataclass
class Corrected:
    z: np.ndarray
    converged: bool
    iterations: int
    K: sp.spmatrix | None = None  # the reduced Hessian at z
    rnorm: float = np.inf
    K_full: sp.spmatrix | None = None  # the full stiffness at z (the next predictor's coupling)


def _solve(K: sp.spmatrix, rhs: np.ndarray, g: np.ndarray, k_ref: float) -> np.ndarray:
    """A descent direction from K dz = rhs: Newton's where it descends, else (K + s I)'s with the
    shift s grown tenfold from 1e-8 k_ref until it does."""
    shift = 0.0
    for _ in range(14):
        try:
            A = K + shift * sp.identity(K.shape[0], format="csc") if shift else K
            dz = spla.splu(A.tocsc()).solve(rhs)
            if np.all(np.isfinite(dz)) and g @ dz < 0:
                return dz
        except RuntimeError:  # exactly singular
            pass
        shift = 1e-8 * k_ref if shift == 0 else 10 * shift
    return -g / k_ref


def correct(p: PeriodicProblem, z, Fp, tol: float, k_ref: float, s: NewtonSettings) -> Corrected:
    """Newton at fixed prescribed components Fp from z, to ||D g|| <= tol (problem.force_norm)."""
    z = np.array(z, float)
    for it in range(s.max_iters + 1):
        E, g, K, K_full = p.linearise(z, Fp)
        rnorm = p.force_norm(g)
        if not np.isfinite(E):
            return Corrected(z, False, it)
        if rnorm <= tol:
            return Corrected(z, True, it, K, rnorm, K_full)
        if it == s.max_iters:
            break
        dz = _solve(K, -g, g, k_ref)
        slope = float(g @ dz)
        a = min(1.0, STEP_FRACTION * p.bound(z, Fp, dz))
        noise = 1e-13 * max(abs(E), k_ref * p.length**2)
        for _ in range(s.max_backtracks):
            if p.energy(z + a * dz, Fp) <= E + ARMIJO * a * slope + noise:
                break
            a *= 0.5
        else:
            return Corrected(z, False, it, rnorm=rnorm)
        z = z + a * dz
    return Corrected(z, False, s.max_iters, rnorm=rnorm)


def predict(p: PeriodicProblem, z, Fp, dFp, K_full: sp.spmatrix, K: sp.spmatrix):
    """The linearised response dz to the prescribed increment dFp at an equilibrium z, and the
    fraction of the increment (at most 1) the state can take along (dz, dFp) with det F > 0."""
    rhs = -(p.T.T @ (K_full @ p.affine(dFp)))
    try:
        dz = spla.splu(K.tocsc()).solve(rhs)
    except RuntimeError:
        dz = np.zeros_like(z)
    if not np.all(np.isfinite(dz)):
        dz = np.zeros_like(z)
    a = min(1.0, STEP_FRACTION * p.bound(z, Fp, dz, dFp))
    return dz, a


def leave_saddle(p: PeriodicProblem, z, Fp, mode: np.ndarray, curvature: float):
    """z moved off a saddle along its unstable mode (curvature < 0 along it), as far as the energy
    falls at least half as fast as its quadratic model says (from a tenth of the cell's size),
    within det F > 0.  The mode's sign is fixed (its largest entry positive), not left to the
    residual's round-off: at a saddle both ways fall."""
    v = 0.1 * p.length * mode / np.max(np.abs(p.scaled(mode)))  # at most a tenth of the cell
    v = v if v[np.argmax(np.abs(v))] > 0 else -v
    E0, g = p.energy(z, Fp), p.linearise(z, Fp)[1]
    slope, curv = float(g @ v), curvature * float(np.sum(p.scaled(v) ** 2))
    bound = p.bound(z, Fp, v)
    a = min(1.0, STEP_FRACTION * bound)
    for _ in range(40):
        if p.energy(z + a * v, Fp) <= E0 + 0.5 * (slope * a + 0.5 * curv * a * a):
            return z + a * v, True
        a *= 0.5
    return z, False


@dataclass
class PathResult:
    """A load path's states at its output points (arrays over the points reached).

    t: the path parameter; F: F_bar (n, 4) in COMPONENTS order; P: the average first
    Piola-Kirchhoff stress (n, 4), over the box's reference area, pores included; energy: the
    average strain energy density; strain_axial, strain_lateral: nominal strains (F_bar - I in
    the load's axial and lateral components; shear's axial strain is gamma);
    poisson: -strain_lateral / strain_axial (secant);
    poisson_incremental: -d strain_lateral / d strain_axial (central differences along the path,
    one-sided at its ends; from rest at the first point); valid: the state passed
    nma.geometry.validity's checks;
    min_J: the smallest det F found there; lowest: the reduced Hessian's lowest eigenvalue over
    k_ref (nan without stability), after any escape; u: the displacements (n, n_points, 2); z: the
    reduced unknowns (n, nz), the fluctuation then F_bar's free components (nma.periodic.gradients
    starts from them).
    critical: the bifurcation, where one was crossed: {t, strain, lowest_before, lowest_after,
    mode_u (n_points, 2)}, or None.  completed: the path reached t = 1; message: why not.
    """

    t: np.ndarray
    F: np.ndarray
    P: np.ndarray
    energy: np.ndarray
    strain_axial: np.ndarray
    strain_lateral: np.ndarray
    poisson: np.ndarray
    poisson_incremental: np.ndarray
    valid: np.ndarray
    min_J: np.ndarray
    lowest: np.ndarray
    u: np.ndarray
    z: np.ndarray
    steps: int
    cuts: int
    completed: bool
    message: str = ""
    critical: dict | None = None
    problems: list = field(default_factory=list)  # (t, what is wrong) of each state not valid
    axial: int = 0  # the load's axial component (COMPONENTS order): P[:, axial] is its stress

    def table(self) -> str:
        """The path as a text table."""
        head = "t       strain_ax  strain_lat  poisson  incr.    P_axial      lowest     valid"
        rows = [head]
        for k in range(len(self.t)):
            rows.append(
                f"{self.t[k]:.4f}  {self.strain_axial[k]:+.5f}  {self.strain_lateral[k]:+.6f}  "
                f"{self.poisson[k]:+.4f}  {self.poisson_incremental[k]:+.4f}  "
                f"{self.P[k, self.axial]:+.4e}  {self.lowest[k]:+.3e}  "
                f"{bool(self.valid[k])}"
            )
        return "\n".join(rows)
