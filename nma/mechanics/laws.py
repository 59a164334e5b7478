"""Hyperelastic laws in plane strain: Neo-Hookean, Mooney-Rivlin, Yeoh, Ogden and Gent.

Every law has the same compressible form, the paper's Neo-Hookean generalised:

    W(F) = psi(lambda_1, lambda_2, lambda_3) - c0 log J + kappa/2 (log J)^2,   lambda_3 = 1 (plane strain)

psi is the law's function of the principal stretches (of the invariants I1, I2 of C = F^T F for all but
Ogden), c0 = dpsi/dlambda at rest makes the reference stress-free, and kappa is the bulk modulus of the
material's Poisson's ratio nu at its initial shear modulus mu0:  kappa = 2 mu0 (1 + nu) / (3 (1 - 2 nu)),
as Neo-Hookean's E / (3 (1 - 2 nu)).  With c0 = mu0 = mu and psi = mu/2 (I1 - 3) the form is Neo-Hookean's,
so a Mooney-Rivlin with C01 = 0, a Yeoh with C20 = C30 = 0 and a one-term Ogden with alpha = 2 are it.
The volumetric term is the part the `mixed` formulation evaluates at each element's mean dilatation.

A material is one array: the law's parameters in `Law.names` order, then nu.  Neo-Hookean's is [E, nu].
Stresses are in the unit of the parameters.
"""
from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from .. import checks
from ..errors import ConfigError
from ..settings import in_range
from .options import LAW_NAMES, MATERIAL_RANGES, MODES

# Ogden's psi needs sum_i c_i^beta over the eigenvalues c_i of the 2 x 2 C.  With m = tr C / 2 and
# x^2 = 1 - det C / m^2 it is m^beta ((1 + x)^beta + (1 - x)^beta): smooth in x^2, but x = sqrt(x^2) is not
# differentiable at equal stretches.  Below SERIES_BELOW the even binomial series in x^2 (to x^(2 SERIES_TERMS - 2),
# truncation under 1e-15 relative there) replaces it; above, the closed form's derivatives lose no more
# than 1e-13 to cancellation.
SERIES_BELOW = 0.01
SERIES_TERMS = 8


def principal_power_sum(C: jnp.ndarray, beta) -> jnp.ndarray:
    """c_1^beta + c_2^beta over the eigenvalues of a symmetric positive definite 2 x 2 C, twice
    differentiable everywhere (equal eigenvalues included)."""
    m = 0.5 * (C[..., 0, 0] + C[..., 1, 1])
    x2 = jnp.clip(1.0 - (C[..., 0, 0] * C[..., 1, 1] - C[..., 0, 1] * C[..., 1, 0]) / m ** 2, 0.0, 1.0)
    near = x2 < SERIES_BELOW
    xs = jnp.where(near, x2, 0.0)
    series, coef = 0.0, 1.0
    for k in range(SERIES_TERMS):
        series = series + coef * xs ** k
        coef = coef * (beta - 2 * k) * (beta - 2 * k - 1) / ((2 * k + 1) * (2 * k + 2))
    x = jnp.sqrt(jnp.where(near, 0.25, x2))
    exact = (1.0 + x) ** beta + (1.0 - x) ** beta
    return m ** beta * jnp.where(near, 2.0 * series, exact)


@dataclass(frozen=True)
class Law:
    """A hyperelastic law: its parameters' names and ranges, its psi, its initial shear modulus."""
    name: str
    names: tuple[str, ...]          # the parameters, in the material array's order (nu follows)

    def ranges(self) -> dict[str, str]:
        return {n: "(-inf, inf)" for n in self.names}

    def shear_modulus(self, p):
        """The initial shear modulus mu0 of the parameters p (the law's, without nu)."""
        raise NotImplementedError

    def stress_free(self, p):
        """c0: the coefficient of -log J that leaves the reference stress-free."""
        raise NotImplementedError

    def psi_invariants(self, p, I1, I2):
        raise NotImplementedError

    def psi_principal(self, p, l1, l2, l3):
        """psi of the principal stretches (any of them, 3D)."""
        sq = (l1 ** 2, l2 ** 2, l3 ** 2)
        return self.psi_invariants(p, sum(sq), sq[0] * sq[1] + sq[1] * sq[2] + sq[2] * sq[0])

    def psi_plane(self, p, C):
        """psi of the 2 x 2 right Cauchy-Green tensor C, lambda_3 = 1 (plane strain)."""
        tr, det = C[..., 0, 0] + C[..., 1, 1], C[..., 0, 0] * C[..., 1, 1] - C[..., 0, 1] * C[..., 1, 0]
        return self.psi_invariants(p, tr + 1.0, det + tr)

    def check(self, values: dict, nu: float, stretches=(0.5, 2.0)) -> None:
        """Refuses parameters outside their ranges, a non-positive shear modulus, or a law that is not
        Drucker-stable for principal stretches in `stretches` (nma.mechanics.laws.drucker_unstable)."""
        from ..settings import check_range
        for n in self.names:
            if n not in values:
                raise ConfigError(f"material.parameters.{n} is missing: law {self.name} takes {list(self.names)}")
            check_range(f"material.parameters.{n}", float(values[n]), self.ranges()[n])
        extra = sorted(set(values) - set(self.names))
        if extra:
            raise ConfigError(f"material.parameters {extra} are not law {self.name}'s: it takes {list(self.names)}")
        p = jnp.asarray([float(values[n]) for n in self.names])
        if not float(self.shear_modulus(p)) > 0:
            raise ConfigError(f"material.parameters {values} give law {self.name} an initial shear modulus "
                              f"{float(self.shear_modulus(p)):g}: it must be positive")
        bad = drucker_unstable(self, p, stretches)
        if bad:
            raise ConfigError(f"material.parameters {values}: law {self.name} is not stable (Drucker) for principal "
                              f"stretches in material.stretches={list(stretches)}: {bad}")


class NeoHookean(Law):
    """The paper's law, parametrised by E (its shear modulus depends on nu too): its closed forms are in
    nma.mechanics.material; Mooney-Rivlin with C01 = 0 is the same psi for fitting."""
    def ranges(self):
        return {"E": MATERIAL_RANGES["E"]}


class MooneyRivlin(Law):
    """psi = C10 (I1 - 3) + C01 (I2 - 3); mu0 = 2 (C10 + C01)."""
    def shear_modulus(self, p):
        return 2.0 * (p[0] + p[1])

    def stress_free(self, p):
        return 2.0 * p[0] + 4.0 * p[1]

    def psi_invariants(self, p, I1, I2):
        return p[0] * (I1 - 3.0) + p[1] * (I2 - 3.0)


class Yeoh(Law):
    """psi = C10 (I1 - 3) + C20 (I1 - 3)^2 + C30 (I1 - 3)^3; mu0 = 2 C10."""
    def shear_modulus(self, p):
        return 2.0 * p[0]

    def stress_free(self, p):
        return 2.0 * p[0]

    def psi_invariants(self, p, I1, I2):
        a = I1 - 3.0
        return p[0] * a + p[1] * a ** 2 + p[2] * a ** 3


class Gent(Law):
    """psi = -mu Jm / 2 log(1 - (I1 - 3) / Jm): stiffens without bound as I1 - 3 nears Jm (the chains'
    limiting extensibility), where the energy is infinite; mu0 = mu."""
    def ranges(self):
        return {"mu": "(0, 1e30]", "Jm": "(0, 1e12]"}

    def shear_modulus(self, p):
        return p[0]

    def stress_free(self, p):
        return p[0]

    def psi_invariants(self, p, I1, I2):
        arg = 1.0 - (I1 - 3.0) / p[1]
        return jnp.where(arg > 0, -0.5 * p[0] * p[1] * jnp.log(jnp.where(arg > 0, arg, 1.0)), jnp.inf)


class Ogden(Law):
    """psi = sum_k mu_k / alpha_k (lambda_1^alpha_k + lambda_2^alpha_k + lambda_3^alpha_k - 3);
    mu0 = sum_k mu_k alpha_k / 2, c0 = sum_k mu_k.  One term with alpha = 2 is Neo-Hookean."""
    def ranges(self):
        return {n: ("[-100, 100]" if n.startswith("alpha") else "(-inf, inf)") for n in self.names}

    def _terms(self, p):
        return [(p[2 * k], p[2 * k + 1]) for k in range(len(self.names) // 2)]

    def shear_modulus(self, p):
        return sum(0.5 * m * a for m, a in self._terms(p))

    def stress_free(self, p):
        return sum(m for m, _ in self._terms(p))

    def psi_principal(self, p, l1, l2, l3):
        return sum(m / a * (l1 ** a + l2 ** a + l3 ** a - 3.0) for m, a in self._terms(p))

    def psi_plane(self, p, C):
        return sum(m / a * (principal_power_sum(C, 0.5 * a) - 2.0) for m, a in self._terms(p))

    def check(self, values, nu, stretches=(0.5, 2.0)):
        for n in self.names:
            if n.startswith("alpha") and n in values and not 0.01 <= abs(float(values[n])) <= 100:
                raise ConfigError(f"material.parameters.{n} must lie in [-100, -0.01] or [0.01, 100], got {values[n]}")
        super().check(values, nu, stretches)


def ogden_names(terms: int) -> tuple[str, ...]:
    return tuple(n for k in range(1, terms + 1) for n in (f"mu{k}", f"alpha{k}"))


NEO_HOOKEAN = NeoHookean("neo_hookean", ("E",))
LAWS = {"neo_hookean": NEO_HOOKEAN, "mooney_rivlin": MooneyRivlin("mooney_rivlin", ("C10", "C01")),
        "yeoh": Yeoh("yeoh", ("C10", "C20", "C30")), "gent": Gent("gent", ("mu", "Jm")),
        **{f"ogden{n}": Ogden(f"ogden{n}", ogden_names(n)) for n in (1, 2, 3)}}


def law_of(name: str, parameters=()) -> Law:
    """The law `name` (one of LAW_NAMES); Ogden's with as many terms as `parameters` has mu's (1 to 3)."""
    if name == "ogden":
        terms = sum(1 for n in parameters if n.startswith("mu"))
        if not 1 <= terms <= 3:
            raise ConfigError(f"material.parameters must give an Ogden law 1 to 3 terms (mu1, alpha1, ...), got "
                              f"{sorted(parameters)}")
        return LAWS[f"ogden{terms}"]
    if name not in LAW_NAMES:
        raise ConfigError(f"material.law must be one of {list(LAW_NAMES)}, got {name!r}")
    return LAWS[name]


# -- homogeneous incompressible deformations: the tests a material is characterised by ----------------
def mode_stretches(mode: str, lam):
    """The principal stretches of an incompressible homogeneous deformation of stretch lam along 1:
    uniaxial tension, equibiaxial tension (1 and 2), planar tension (pure shear: 2 held)."""
    if mode == "uniaxial":
        return lam, lam ** -0.5, lam ** -0.5
    if mode == "biaxial":
        return lam, lam, lam ** -2.0
    if mode == "planar":
        return lam, jnp.ones_like(lam), 1.0 / lam
    raise ConfigError(f"mode must be one of {list(MODES)}, got {mode!r}")


def _true_stress(law: Law, p, mode: str, lam):
    """sigma_11 - sigma_33 = lam_1 dpsi/dlam_1 - lam_3 dpsi/dlam_3 (sigma_33 = 0: the free direction's pressure)."""
    ls = jnp.stack(mode_stretches(mode, lam))
    g = jax.grad(lambda l: law.psi_principal(p, l[0], l[1], l[2]))(ls)
    return ls[0] * g[0] - ls[2] * g[2]


def checked_parameters(where: str, law: Law, p) -> jnp.ndarray:
    """p as the array of `law`'s parameters (Law.names, without nu): TypeError or ConfigError naming
    `where`, the law and what it takes where p is not that many real numbers, finite and in their
    ranges (where concrete), or where the law has no incompressible psi (Neo-Hookean's E needs
    nu)."""
    if not isinstance(law, Law):
        raise TypeError(f"{where}: law must be a Law (nma.mechanics.laws.law_of(name)), got "
                        f"{type(law).__name__} {law!r:.80}")
    if isinstance(law, NeoHookean):
        raise ConfigError(f"{where}: law neo_hookean is parametrised by E and nu, not by an "
                          "incompressible psi: take law mooney_rivlin with C10 = E / (4 (1 + nu)), "
                          "C01 = 0")
    names = ", ".join(law.names)
    takes = f"law {law.name} takes [{names}]"
    try:
        p = checks.array(where, "p", p, (None,))
    except ValueError as e:
        raise ConfigError(f"{e}; {takes}") from None
    if p.shape[0] != len(law.names):
        raise ConfigError(f"{where}: p must hold {len(law.names)} parameters, got {p.shape[0]}: "
                          f"{takes}")
    if not isinstance(p, jax.core.Tracer):
        values = dict(zip(law.names, np.asarray(p, dtype=float).tolist()))
        for n, spec in law.ranges().items():
            if not in_range(values[n], spec):
                raise ConfigError(f"{where}: p = [{names}] must have {n} in {spec} "
                                  f"(law {law.name}), got {values[n]:g}")
        alphas = [a for n, a in values.items() if n.startswith("alpha") and abs(a) < 0.01]
        if alphas:
            raise ConfigError(f"{where}: law {law.name}'s exponents alpha must lie in "
                              f"[-100, -0.01] or [0.01, 100], got {alphas[0]:g}")
    return p


def _checked_mode(where: str, mode) -> str:
    if mode not in MODES:
        raise ConfigError(f"{where}: mode must be one of {list(MODES)}, got {mode!r}")
    return mode


def nominal_stress(law: Law, p, mode: str, lam):
    """The engineering (first Piola) stress along 1 of the incompressible `mode` at stretch lam: what a
    tensile test measures, the force over the undeformed section.  p: the law's parameters
    (Law.names); lam: a positive stretch or an array of them."""
    p, mode = checked_parameters("nominal_stress", law, p), _checked_mode("nominal_stress", mode)
    lam = checks.array("nominal_stress", "lam", jnp.atleast_1d(jnp.asarray(lam, float)), (None,))
    if not isinstance(lam, jax.core.Tracer) and not np.all(np.asarray(lam) > 0):
        raise ConfigError(f"nominal_stress: lam must hold positive stretches, got "
                          f"{np.asarray(lam).min():g}")
    return jax.vmap(lambda l: _true_stress(law, p, mode, l) / l)(jnp.atleast_1d(jnp.asarray(lam, float)))


def drucker_unstable(law: Law, p, stretches=(0.5, 2.0), samples: int = 201) -> str:
    """'' where d sigma / d log(lambda) > 0 (Drucker's condition for these one-parameter paths) in every mode
    at every stretch in `stretches` (low, high: 0 < low < high); else the first mode and stretch
    where it fails."""
    from ..runtime import configure_jax
    configure_jax()  # float64: a config is checked before any solve has set it
    p = checked_parameters("drucker_unstable", law, p)
    lo, hi = checks.array("drucker_unstable", "stretches", stretches, (2,)).tolist()
    if not 0 < lo < hi:
        raise ConfigError(f"drucker_unstable: stretches must be (low, high) with 0 < low < high, "
                          f"got {[lo, hi]}")
    samples = checks.integer("drucker_unstable", "samples", samples, "[2, 1000000]")
    lam = np.exp(np.linspace(np.log(stretches[0]), np.log(stretches[1]), samples))
    for mode in MODES:
        slope = np.asarray(jax.vmap(jax.grad(lambda e: _true_stress(law, p, mode, jnp.exp(e))))(jnp.log(lam)))
        bad = np.flatnonzero(~(slope > 0))
        if bad.size:
            finite = np.isfinite(float(law.psi_principal(p, *mode_stretches(mode, jnp.asarray(lam[bad[0]])))))
            why = "softens (d sigma / d log stretch <= 0)" if finite and np.isfinite(slope[bad[0]]) else \
                "lies beyond the law's limit (its energy is not finite)"
            return f"{mode} tension at stretch {lam[bad[0]]:.3g} {why}"
    return ""


def principal_stretch_range(F: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """The smallest and largest in-plane principal stretch over deformation gradients F (..., 2, 2): the
    strain range a state asks of its law (lambda_3 = 1 in plane strain)."""
    C = jnp.einsum("...ki,...kj->...ij", F, F)
    m = 0.5 * (C[..., 0, 0] + C[..., 1, 1])
    r = jnp.sqrt(jnp.maximum(m ** 2 - (C[..., 0, 0] * C[..., 1, 1] - C[..., 0, 1] * C[..., 1, 0]), 0.0))
    return jnp.sqrt(jnp.min(jnp.maximum(m - r, 0.0))), jnp.sqrt(jnp.max(m + r))
