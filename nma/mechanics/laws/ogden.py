"""Ogden: a sum of one to three powers of the principal stretches."""

from __future__ import annotations

import numpy as np

from ...errors import ConfigError
from .base import Parameter, StretchLaw, register

EXPONENTS = "[-100, -0.01] or [0.01, 100]"  # an exponent at 0 is a term of no stress


@register
class Ogden(StretchLaw):
    """psi = sum_k mu_k / alpha_k (lambda_1^alpha_k + lambda_2^alpha_k + lambda_3^alpha_k - 3), one
    to three terms (k); mu0 = sum_k mu_k alpha_k / 2, c0 = sum_k mu_k.  One term with alpha = 2 is
    Neo-Hookean."""

    name = "ogden"
    parameters = (
        Parameter("mu1", 0.02447, "(-inf, inf)", "the first term's modulus"),
        Parameter("alpha1", 2.0, EXPONENTS, "the first term's exponent", stress=False),
        Parameter("mu2", -0.002447, "(-inf, inf)", "the second term's modulus"),
        Parameter("alpha2", -2.0, EXPONENTS, "the second term's exponent", stress=False),
        Parameter("mu3", None, "(-inf, inf)", "the third term's modulus"),
        Parameter("alpha3", None, EXPONENTS, "the third term's exponent", stress=False),
    )

    @classmethod
    def of(cls, given=()):
        """As many terms as `given` names mu's (1 to 3); none given: the defaults' two."""
        asked = [n for n in given if n.startswith("mu")]
        terms = (
            len(asked)
            if given
            else sum(1 for p in cls.parameters if p.name.startswith("mu") and p.default is not None)
        )
        if not 1 <= terms <= 3:
            raise ConfigError(
                "material.parameters must give an Ogden law 1 to 3 terms (mu1, alpha1, "
                f"...), got {sorted(given)}"
            )
        return cls(tuple(p.name for p in cls.parameters[: 2 * terms]))

    def terms(self, q):
        return [(q[f"mu{k}"], q[f"alpha{k}"]) for k in range(1, len(self.names) // 2 + 1)]

    def shear_modulus(self, q):
        return sum(0.5 * m * a for m, a in self.terms(q))

    def stress_free(self, q):
        return sum(m for m, _ in self.terms(q))

    def psi(self, q, excess):
        return sum(m / a * excess(a) for m, a in self.terms(q))

    def fit_start(self, mu0, stretches, i1_max):
        terms = len(self.names) // 2
        alphas = [2.0, -2.0, 5.0][:terms]
        first = [v for a in alphas for v in (2.0 * mu0 / (terms * a), a)]
        return (
            first,
            [v for _ in range(terms) for v in (-np.inf, -100.0)],
            [v for _ in range(terms) for v in (np.inf, 100.0)],
        )

    def fit_draw(self, guess, mu0, rng):
        """Exponents drawn across [-10, 10] (at least 0.5 from 0), each term's modulus sharing
        mu0."""
        a = rng.uniform(-10.0, 10.0, len(self.names) // 2)
        a = np.where(np.abs(a) < 0.5, 0.5, a)
        guess[1::2] = a
        guess[0::2] = 2.0 * mu0 / (len(a) * a)
        return guess
