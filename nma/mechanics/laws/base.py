"""What every hyperelastic law shares: the declaration of its parameters, the registry it joins on
import, and the reductions of its 3D strain energy psi to plane strain and to the principal
stretches.

A law is a class in a module of its own, a subclass of InvariantLaw (psi of the invariants I1, I2 of
the 3D right Cauchy-Green tensor C = F^T F) or of StretchLaw (psi of the sums of powers of the three
principal stretches), decorated with `@register`.  It declares `name` and `parameters` (Parameter:
name, default, range, meaning, in the material array's order) and defines psi, `shear_modulus` (mu0)
and `stress_free` (c0 = dpsi/dlambda at rest), each a function of `q`, the material's parameters by
name (the law's and nu).  A law whose psi is its whole energy (St Venant-Kirchhoff) sets
`volume_term` False and says where it is unstable (`drucker`).  Plane strain (F_33 = 1) is the
reduction `psi_plane`, written once here.

This module imports no JAX, so that the config schema reads the declarations without it: `jnp` is
jax.numpy, imported at its first use.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from importlib import import_module
from typing import ClassVar

from ...errors import ConfigError
from ...registry import Registry
from ...settings import in_range


class _Lazy:
    """A module imported at the first read of one of its attributes."""

    def __init__(self, name: str):
        self._name = name

    def __getattr__(self, attribute):
        return getattr(import_module(self._name), attribute)


jnp = _Lazy("jax.numpy")
LAWS: Registry = Registry("material.law")  # name -> the law's class (nma.mechanics.laws.law_of)


@dataclass(frozen=True)
class Parameter:
    """One parameter of a law, declared once: the config's checks, the settings reference, the law's
    default material file and a fit's starting point all read it."""

    name: str
    default: float | None  # None: optional, left out of the law's defaults (Ogden's third term)
    range: str  # an interval, "(0, 1e30]", or several joined by " or "
    doc: str
    stress: bool = True  # in the unit of stress (material.unit); else a pure number

    def admits(self, value: float) -> bool:
        return any(in_range(float(value), spec.strip()) for spec in self.range.split(" or "))

    def bounds(self) -> tuple[float, float]:
        """The smallest and largest value of the range (its ends, open or not)."""
        ends = [
            float(x) for spec in self.range.split(" or ") for x in spec.strip()[1:-1].split(",")
        ]
        return min(ends), max(ends)


# Poisson's ratio, every law's: 0.5 is incompressible, which a displacement model cannot represent
POISSON = Parameter(
    "nu",
    0.3,
    "(-1, 0.5)",
    "Poisson's ratio: 0.5 is incompressible, which a displacement model cannot represent",
    stress=False,
)


class Named(Mapping):
    """A material's parameters by name: the law's, each read an index into their array `p` (traced
    or not), and nu where given."""

    def __init__(self, names: tuple[str, ...], p, nu=None):
        self._index, self._p, self._nu = {n: i for i, n in enumerate(names)}, p, nu

    def __getitem__(self, name: str):
        if name == "nu" and self._nu is not None:
            return self._nu
        return self._p[self._index[name]]

    def __iter__(self):
        return iter((*self._index, *(("nu",) if self._nu is not None else ())))

    def __len__(self) -> int:
        return len(self._index) + (self._nu is not None)


def register(cls):
    """Class decorator: the law `cls` in LAWS under its `name`."""
    LAWS.register(cls.name)(cls)
    return cls


@dataclass(frozen=True)
class Law:
    """A hyperelastic law with the parameters `names` (all it declares but for a law of a variable
    number of terms).  The material's strain energy is the compressible form
    W = psi - c0 log J + k/2 (log J)^2, k the bulk modulus kappa or the Lame constant lambda
    (material.volumetric: nma.mechanics.material)."""

    names: tuple[str, ...]  # the parameters taken, in the material array's order (nu follows)

    name: ClassVar[str]
    parameters: ClassVar[tuple[Parameter, ...]]
    # nma.mechanics.material writes W, its stress and its tangent in closed form (Neo-Hookean's psi)
    closed_form: ClassVar[bool] = False
    # Drucker-stable at every stretch for all admissible parameters: the config skips the check
    # (nma.mechanics.laws.homogeneous.check_stable)
    stable: ClassVar[bool] = False
    # False: psi is the law's whole energy W, without -c0 log J + kappa/2 (log J)^2 (kappa is then
    # only the inversion barrier's scale; the `mixed` formulation, which evaluates that term per
    # element, and the incompressible tests of nma.mechanics.laws.homogeneous do not apply)
    volume_term: ClassVar[bool] = True
    # the principal stretches its material file asks it to be stable over (material.stretches)
    stretch_range: ClassVar[tuple[float, float]] = (0.5, 2.0)

    @classmethod
    def of(cls, given=()) -> "Law":
        """The law taking the parameters that `given` (names) asks for: all it declares."""
        return cls(tuple(p.name for p in cls.parameters))

    def declared(self, name: str) -> Parameter:
        return next(p for p in (*self.parameters, POISSON) if p.name == name)

    def defaults(self) -> dict[str, float]:
        """The declared defaults of the parameters taken."""
        return {n: self.declared(n).default for n in self.names}

    def named(self, p, nu=None) -> Named:
        """q: the parameter array p (in `names` order) and nu, by name."""
        return Named(self.names, p, nu)

    def out_of_range(self, values: Mapping) -> tuple[str, str] | None:
        """(name, range) of the first concrete parameter outside its range; None if none is."""
        bad = next((n for n in self.names if not self.declared(n).admits(values[n])), None)
        return None if bad is None else (bad, self.declared(bad).range)

    # -- the law proper ----------------------------------------------------------------------
    def shear_modulus(self, q):
        """mu0: the initial shear modulus."""
        raise NotImplementedError

    def stress_free(self, q):
        """c0: the coefficient of -log J that leaves the reference stress-free."""
        raise NotImplementedError

    def bulk_modulus(self, q, mu0):
        """kappa: Neo-Hookean's bulk modulus at the initial shear modulus mu0 and q's nu, the
        paper's coefficient of (log J)^2 / 2 (material.volumetric=bulk) and the scale of the
        inversion barrier."""
        return 2.0 * mu0 * (1.0 + q["nu"]) / (3.0 * (1.0 - 2.0 * q["nu"]))

    def lame_modulus(self, q, mu0):
        """lambda: the coefficient of (log J)^2 / 2 that gives the law's 3D compressible form the
        Poisson's ratio q["nu"] at small strain, the Lame constant 2 mu0 nu / (1 - 2 nu) less psi's
        own share of it (psi_lambda); Neo-Hookean's is kappa - 2 mu0 / 3."""
        nu = q["nu"]
        return 2.0 * mu0 * nu / (1.0 - 2.0 * nu) - self.psi_lambda(q)

    def psi_lambda(self, q):
        """psi's own share of the Lame constant at rest, d2 psi(a, b, 1) / da db at a = b = 1 (the
        terms -c0 log J have none): Mooney-Rivlin's 4 C01, a Yeoh's 8 C20.  By automatic
        differentiation of psi_principal, unless a law gives it in closed form."""
        import jax

        f = lambda a, b: self.psi_principal(q, a, b, 1.0)
        one = jnp.asarray(1.0)
        return jax.grad(jax.grad(f, 0), 1)(one, one)

    def psi_principal(self, q, l1, l2, l3):
        """psi of the three principal stretches."""
        raise NotImplementedError

    def psi_plane(self, q, C):
        """psi in plane strain: of the 2 x 2 C, the third principal stretch 1 (F_33 = 1)."""
        raise NotImplementedError

    def drucker(self, low: float, high: float) -> str | None:
        """Where the law is not Drucker-stable at principal stretches in [low, high] ('' nowhere),
        for a law that knows it in closed form; None: the incompressible tests decide
        (nma.mechanics.laws.homogeneous.drucker_unstable)."""
        return None

    # -- a config's check ----------------------------------------------------------------------
    def check(self, values: Mapping, nu: float) -> None:
        """Refuses parameters missing, not the law's or outside their ranges, or a non-positive
        shear modulus: a ConfigError naming the parameter.  Its stability is check_stable's."""
        for n in self.names:
            if n not in values:
                raise ConfigError(
                    f"material.parameters.{n} is missing: law {self.name} takes {list(self.names)}"
                )
        extra = sorted(set(values) - set(self.names))
        if extra:
            raise ConfigError(
                f"material.parameters {extra} are not law {self.name}'s: it takes "
                f"{list(self.names)}"
            )
        bad = self.out_of_range(values)
        if bad:
            raise ConfigError(
                f"material.parameters.{bad[0]} must be a finite number in {bad[1]}, "
                f"got {values[bad[0]]!r}"
            )
        mu0 = float(self.shear_modulus({**{n: float(values[n]) for n in self.names}, "nu": nu}))
        if not mu0 > 0:
            raise ConfigError(
                f"material.parameters {dict(values)} give law {self.name} an initial "
                f"shear modulus {mu0:g}: it must be positive"
            )

    # -- a fit's start (nma.fit) ---------------------------------------------------------------
    def fit_start(self, mu0: float, stretches, i1_max: float):
        """(first guess, lower bounds, upper bounds) of a least-squares fit to data of initial shear
        modulus mu0 (stretches: the data's; i1_max: their largest I1): the declared defaults, those
        in the unit of stress scaled to mu0, within the declared ranges."""
        defaults = self.defaults()
        scale = mu0 / float(self.shear_modulus({**defaults, "nu": POISSON.default}))
        first = [v * scale if self.declared(n).stress else v for n, v in defaults.items()]
        lo, hi = zip(*(self.declared(n).bounds() for n in self.names))
        return first, list(lo), list(hi)

    def fit_draw(self, guess, mu0: float, rng):
        """Another initial guess from `guess`, the first scaled by random factors in [0.3, 3]: as
        it is, or with what the law draws itself (Ogden's exponents)."""
        return guess

    def fit_notes(self, values: Mapping, upper, nu: float) -> list[str]:
        """What a reader of a fit must know of its parameters `values` (upper: the fit's bounds)."""
        return []


# The Ogden-type sum c_1^beta + c_2^beta over the eigenvalues of a 2 x 2 C: with m = tr C / 2 and
# x^2 = 1 - det C / m^2 it is m^beta ((1 + x)^beta + (1 - x)^beta), smooth in x^2, but x = sqrt(x^2)
# is not differentiable at equal stretches.  Below SERIES_BELOW the even binomial series in x^2 (to
# x^(2 SERIES_TERMS - 2), truncation under 1e-15 relative there) replaces it; above, the closed
# form's derivatives lose no more than 1e-13 to cancellation.
SERIES_BELOW = 0.01
SERIES_TERMS = 8


def principal_power_sum(C, beta):
    """c_1^beta + c_2^beta over the eigenvalues of a symmetric positive definite 2 x 2 C, twice
    differentiable everywhere (equal eigenvalues included)."""
    m = 0.5 * (C[..., 0, 0] + C[..., 1, 1])
    # x^2 = ((c_11 - c_22)^2 / 4 + c_12 c_21) / m^2: no difference of near-equal terms, and no clip
    # at 0, whose derivative (1/2 there) would halve the tangent at equal stretches
    half_gap = 0.5 * (C[..., 0, 0] - C[..., 1, 1])
    x2 = jnp.minimum((half_gap**2 + C[..., 0, 1] * C[..., 1, 0]) / m**2, 1.0)
    near = x2 < SERIES_BELOW
    xs = jnp.where(near, x2, 0.0)
    series, coef = 0.0, 1.0
    for k in range(SERIES_TERMS):
        series = series + coef * xs**k
        coef = coef * (beta - 2 * k) * (beta - 2 * k - 1) / ((2 * k + 1) * (2 * k + 2))
    x = jnp.sqrt(jnp.where(near, 0.25, x2))
    exact = (1.0 + x) ** beta + (1.0 - x) ** beta
    return m**beta * jnp.where(near, 2.0 * series, exact)


class InvariantLaw(Law):
    """A law whose psi(q, I1, I2) is a function of the invariants of the 3D C = F^T F."""

    def psi(self, q, I1, I2):
        raise NotImplementedError

    def psi_principal(self, q, l1, l2, l3):
        sq = (l1**2, l2**2, l3**2)
        return self.psi(q, sum(sq), sq[0] * sq[1] + sq[1] * sq[2] + sq[2] * sq[0])

    def psi_plane(self, q, C):
        tr = C[..., 0, 0] + C[..., 1, 1]
        det = C[..., 0, 0] * C[..., 1, 1] - C[..., 0, 1] * C[..., 1, 0]
        return self.psi(q, tr + 1.0, det + tr)


class StretchLaw(Law):
    """A law whose psi(q, excess) is a function of the principal stretches through
    excess(a) = lambda_1^a + lambda_2^a + lambda_3^a - 3 (zero at rest)."""

    def psi(self, q, excess):
        raise NotImplementedError

    def psi_principal(self, q, l1, l2, l3):
        return self.psi(q, lambda a: l1**a + l2**a + l3**a - 3.0)

    def psi_plane(self, q, C):
        return self.psi(q, lambda a: principal_power_sum(C, 0.5 * a) - 2.0)
