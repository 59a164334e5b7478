"""The model's material: a hyperelastic law (nma.mechanics.laws) with its treatment of volume
change.

The material's strain energy is the law's compressible form W = psi - c0 log J + k/2 (log J)^2
in plane strain; its stress and tangent are W's derivatives by automatic differentiation, or, for a
law whose psi is Neo-Hookean's (`Law.closed_form`), the closed forms here:

    W(F) = mu/2 (I1 - 2 - 2 log J) + k/2 (log J)^2,  mu = E / (2 (1 + nu)),
    k = kappa = E / (3 (1 - 2 nu))             (volumetric `bulk`, the paper's), or
    k = lambda = E nu / ((1 + nu) (1 - 2 nu))  (volumetric `lame`: nu is the 3D Poisson's ratio).

With `lame` a small strain in the plane has the plane-strain moduli of a 3D solid, E / (1 - nu^2)
under uniaxial stress with the in-plane Poisson's ratio nu / (1 - nu); with `bulk` they are those
of Lame constants (kappa, mu), 4 mu (kappa + mu) / (kappa + 2 mu) and kappa / (kappa + 2 mu)
(plane_moduli).  kappa stays the inversion barrier's scale in both.

The material's parameters are an array (the law's, then nu; Neo-Hookean's [E, nu]) so that they
are a differentiable input like any other; the law reads them by name.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import jax
import jax.numpy as jnp

from .. import checks
from ..errors import ConfigError
from ..settings import check_range
from .laws import POISSON, Law, law_of
from .laws.base import Named
from .options import FORMULATIONS, VOLUMETRIC


@dataclass(frozen=True)
class Material:
    """The model's material: a law (nma.mechanics.laws; the paper's Neo-Hookean by default) with
    its treatment of volume change, `formulation` (one of FORMULATIONS: the volume term at every
    Gauss point, or at each element's mean dilatation, which does not lock as nu -> 0.5:
    nma.mechanics.energy) and the coefficient of its volume term, `volumetric` (one of
    VOLUMETRIC: the Lame constant of the 3D law, or the bulk modulus, the paper's and the default
    here; a law without a volume term ignores it).  Its parameters (`names`: the law's, then nu;
    Neo-Hookean's [E, nu]) are an array given to every solve, so that they are differentiable like
    the geometry."""

    formulation: str = "displacement"
    law: Law = field(default_factory=lambda: law_of("neo_hookean"))
    volumetric: str = "bulk"

    def __post_init__(self):
        if self.formulation not in FORMULATIONS:
            raise ConfigError(
                f"material.formulation must be one of {list(FORMULATIONS)}, "
                f"got {self.formulation!r}"
            )
        if self.volumetric not in VOLUMETRIC:
            raise ConfigError(
                f"material.volumetric must be one of {list(VOLUMETRIC)}, got {self.volumetric!r}"
            )
        if self.mixed and not self.law.volume_term:
            raise ConfigError(
                f"material.formulation=mixed evaluates the volume term per element: law "
                f"{self.law.name} has none (its energy is whole), set "
                "material.formulation=displacement"
            )

    @property
    def mixed(self) -> bool:
        return self.formulation == "mixed"

    @property
    def names(self) -> tuple[str, ...]:
        """The parameter array's entries by name: the law's parameters, then nu."""
        return (*self.law.names, POISSON.name)

    @property
    def n_params(self) -> int:
        """The length of the parameter array: the law's parameters and nu."""
        return len(self.names)

    def named(self, params: jnp.ndarray) -> Named:
        """The parameter array by name (q of the law's functions)."""
        return self.law.named(params[:-1], params[-1])

    def nu(self, params: jnp.ndarray):
        """Poisson's ratio of the parameter array."""
        return self.named(params)[POISSON.name]

    def check(self, params, where: str = "equilibrium") -> None:
        """Refuses concrete parameters of another count than the law's and nu, or outside the law's
        ranges (ValueError naming `where`, the law and the entry)."""
        names = self.names
        if len(params) != len(names):
            raise ValueError(
                f"{where}: mat must be law {self.law.name}'s [{', '.join(names)}]: "
                f"{len(names)} numbers, got {len(params)}"
            )
        for name, number in zip(names, params):
            spec = self.law.declared(name)
            if not spec.admits(float(number)):
                raise ValueError(
                    f"{where}: mat = [{', '.join(names)}] must have {name} in "
                    f"{spec.range}, got {float(number):g}"
                )
        problem = self.unbounded_volume_term(params)
        if problem:
            raise ValueError(f"{where}: mat = [{', '.join(names)}]: {problem}")

    def unbounded_volume_term(self, params, prefix: str = "") -> str | None:
        """Why the `lame` volume coefficient k of concrete `params` is negative, or None (k >= 0,
        `bulk`, or no volume term); the settings named with `prefix` ("material.").  With k < 0
        the energy -c0 log J + k/2 (log J)^2 falls without bound as J -> 0 (collapsed states
        would be minima); kappa > 0 for every admissible nu."""
        if self.volumetric != "lame" or not self.law.volume_term:
            return None
        q = self.named(jnp.asarray(params, dtype=jnp.float64))
        mu0 = self.law.shear_modulus(q)
        k = float(self.law.lame_modulus(q, mu0))
        if k >= 0:
            return None
        own, nu = float(self.law.psi_lambda(q)), float(q["nu"])
        lowest = own / (2.0 * (float(mu0) + own))  # where 2 mu0 nu / (1 - 2 nu) = own
        cause = (
            f"psi's own share of the Lame constant, {own:.4g}, exceeds 2 mu0 nu / (1 - 2 nu)"
            if own > 0
            else "a negative Poisson's ratio gives a negative Lame constant"
        )
        return (
            f"{prefix}volumetric=lame gives law {self.law.name} the volume coefficient {k:.4g} < 0 "
            f"at {prefix}nu = {nu:g} ({cause}), and the energy would fall without bound as J -> 0: "
            f"{prefix}nu must be at least {lowest:.4g} for lame, or set {prefix}volumetric=bulk"
        )

    def moduli(self, params: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
        """The initial shear and the bulk modulus (mu, kappa) of the parameters: kappa is the
        volume term's coefficient with volumetric `bulk` only (volume_modulus), and the scale of
        the inversion barrier with either."""
        q = self.named(params)
        mu = self.law.shear_modulus(q)
        return mu, self.law.bulk_modulus(q, mu)

    def volume_modulus(self, params: jnp.ndarray, moduli=None):
        """k, the coefficient of the volume term k/2 (log J)^2: the bulk modulus kappa (`bulk`),
        or the law's Lame constant (`lame`: Law.lame_modulus).  `moduli`: (mu, kappa) of the
        parameters where the caller has them (one path for their derivatives, as the paper's)."""
        mu, kappa = self.moduli(params) if moduli is None else moduli
        if self.volumetric == "bulk":
            return kappa
        return self.law.lame_modulus(self.named(params), mu)

    def point_terms(self, params: jnp.ndarray, volumetric: bool = True):
        """W(F), P(F) = dW/dF and dP/dF as functions of deformation gradients (..., 2, 2): with or
        without the volumetric term k/2 (log J)^2 (the `mixed` formulation adds it per
        element)."""
        mu, kappa = self.moduli(params)
        k = self.volume_modulus(params, (mu, kappa)) if volumetric and self.law.volume_term else 0.0
        if self.law.closed_form:
            return (
                jnp.vectorize(lambda f: neo_hookean(f, mu, k), signature="(2,2)->()"),
                lambda F: piola(F, mu, k),
                lambda F: tangent(F, mu, k),
            )
        return self.derived_terms(params, k)

    def plane_moduli(self, params: jnp.ndarray):
        """(E', nu', G): the plane modulus C_1111 - C_1122^2 / C_2222 and the in-plane Poisson's
        ratio C_1122 / C_2222 under uniaxial plane-strain stress at small strain, and the shear
        modulus C_1212, of the tangent C at rest.  C_1111 and C_1122 are W's second derivatives in
        the principal stretches (a, b, 1) at rest, taken of psi_principal (the 2 x 2 reduction's
        branch at equal stretches stays out of it) and C_1212 = (C_1111 - C_1122) / 2 (isotropy)."""
        q = self.named(params)
        c0, k = self.law.stress_free(q), self.volume_modulus(params)

        def W(a, b):
            psi = self.law.psi_principal(q, a, b, 1.0)
            if not self.law.volume_term:
                return psi
            logJ = jnp.log(a * b)
            return psi - c0 * logJ + 0.5 * k * logJ**2

        one = jnp.asarray(1.0)
        c11 = jax.grad(jax.grad(W, 0), 0)(one, one)
        c12 = jax.grad(jax.grad(W, 0), 1)(one, one)
        return c11 - c12**2 / c11, c12 / c11, 0.5 * (c11 - c12)

    def derived_terms(self, params: jnp.ndarray, k):
        """W(F) = psi - c0 log J + k/2 (log J)^2 of the law, and its first and second derivatives by
        automatic differentiation (every law's; a closed-form law's check)."""
        q = self.named(params)
        c0 = self.law.stress_free(q)

        def W(f):
            if not self.law.volume_term:  # psi is the whole energy (St Venant-Kirchhoff)
                return self.law.psi_plane(q, f.T @ f)
            logJ = jnp.log(det2(f))
            return self.law.psi_plane(q, f.T @ f) - c0 * logJ + 0.5 * k * logJ**2

        return (
            jnp.vectorize(W, signature="(2,2)->()"),
            jnp.vectorize(jax.grad(W), signature="(2,2)->(2,2)"),
            jnp.vectorize(jax.hessian(W), signature="(2,2)->(2,2,2,2)"),
        )


def plane_strain_record(model: Material, params) -> dict:
    """What a run's material gives in the plane at small strain (nma.simulate's `plane_strain`):
    its volume term's form (None: a law without one), the plane modulus and in-plane Poisson's
    ratio under uniaxial plane-strain stress (Material.plane_moduli), and the 3D-consistent values
    E / (1 - nu^2), nu / (1 - nu) of E = 2 mu0 (1 + nu), which `lame` has."""
    plane, poisson, _ = (float(x) for x in model.plane_moduli(params))
    nu = float(model.nu(params))
    E = 2.0 * float(model.moduli(params)[0]) * (1.0 + nu)
    return {
        "volumetric": model.volumetric if model.law.volume_term else None,
        "modulus": plane,
        "poisson": poisson,
        "modulus_3d_consistent": E / (1.0 - nu**2),
        "poisson_3d_consistent": nu / (1.0 - nu),
    }


def material(E: float, nu: float) -> jnp.ndarray:
    """Neo-Hookean's [E, nu] as a float64 array, checked against their declared ranges."""
    law = law_of("neo_hookean")
    for name, value in (("E", E), ("nu", nu)):
        check_range(
            f"material.{name}", checks.real("material", name, value), law.declared(name).range
        )
    return jnp.array([E, nu], dtype=jnp.float64)


def from_lame(mu: float, kappa: float) -> jnp.ndarray:
    """[E, nu] for a given shear modulus mu and (paper-formula) bulk modulus kappa, both
    positive."""
    mu = checks.number("from_lame", "mu", mu, "(0, inf)")
    kappa = checks.number("from_lame", "kappa", kappa, "(0, inf)")
    E = 9.0 * kappa * mu / (3.0 * kappa + mu)
    nu = (3.0 * kappa - 2.0 * mu) / (2.0 * (3.0 * kappa + mu))
    return material(E, nu)


def det2(F: jnp.ndarray) -> jnp.ndarray:
    return F[..., 0, 0] * F[..., 1, 1] - F[..., 0, 1] * F[..., 1, 0]


def neo_hookean(F: jnp.ndarray, mu, kappa) -> jnp.ndarray:
    """Energy density of one 2x2 deformation gradient. Defined for J > 0 only: callers keep
    J > 0."""
    J = det2(F)
    logJ = jnp.log(J)
    return 0.5 * mu * (jnp.sum(F * F) - 2.0 - 2.0 * logJ) + 0.5 * kappa * logJ**2


def _inverse(F):
    return (
        jnp.stack(
            [
                jnp.stack([F[..., 1, 1], -F[..., 0, 1]], -1),
                jnp.stack([-F[..., 1, 0], F[..., 0, 0]], -1),
            ],
            -2,
        )
        / det2(F)[..., None, None]
    )


def piola(F, mu, kappa):
    """First Piola stress P = dW/dF = mu (F - F^-T) + kappa log J F^-T (closed form)."""
    FinvT = jnp.swapaxes(_inverse(F), -1, -2)
    return mu * (F - FinvT) + kappa * jnp.log(det2(F))[..., None, None] * FinvT


def tangent(F, mu, kappa):
    """dP/dF: C_ijkl = mu d_ik d_jl + (mu - kappa log J) Fi_jk Fi_li + kappa Fi_ji Fi_lk,
    Fi = F^-1."""
    Fi = _inverse(F)
    logJ = jnp.log(det2(F))[..., None, None, None, None]
    eye = jnp.eye(2)
    return (
        mu * jnp.einsum("ik,jl->ijkl", eye, eye)
        + (mu - kappa * logJ) * jnp.einsum("...jk,...li->...ijkl", Fi, Fi)
        + kappa * jnp.einsum("...ji,...lk->...ijkl", Fi, Fi)
    )


def det_roots(F, dF):
    """(..., 2) the positive roots t of det(F + t dF) = c0 + c1 t + c2 t^2 (2 x 2 matrices; inf
    where there is none), computed without cancellation."""
    c0 = det2(F)
    c1 = (
        F[..., 0, 0] * dF[..., 1, 1]
        + dF[..., 0, 0] * F[..., 1, 1]
        - F[..., 0, 1] * dF[..., 1, 0]
        - dF[..., 0, 1] * F[..., 1, 0]
    )
    c2 = det2(dF)
    inf = jnp.inf
    disc_ = c1 * c1 - 4.0 * c2 * c0
    sq = jnp.sqrt(jnp.maximum(disc_, 0.0))
    q = -0.5 * (c1 + jnp.where(c1 >= 0, sq, -sq))
    safe_q = jnp.where(q == 0, 1.0, q)
    small_c2 = jnp.abs(c2) <= 1e-14 * (jnp.abs(c1) + jnp.abs(c0))
    r1 = jnp.where(small_c2, -c0 / jnp.where(c1 == 0, 1.0, c1), q / jnp.where(c2 == 0, 1.0, c2))
    r2 = jnp.where(small_c2, inf, c0 / safe_q)
    r1 = jnp.where((r1 > 0) & ((disc_ >= 0) | small_c2) & ~((c1 == 0) & small_c2), r1, inf)
    r2 = jnp.where((r2 > 0) & (disc_ >= 0) & (q != 0), r2, inf)
    return jnp.stack([r1, r2], -1)
