"""The hyperelastic laws (nma.mechanics.laws, nma.mechanics.material.Material): stresses of
homogeneous deformations against closed forms written out here by hand, derivatives against central
differences, Neo-Hookean's special cases, Drucker stability, a solve's gradient with respect to the
parameters, and Arruda-Boyce against the eight-chain model (each law's declaration, files and
checks: test_law_modules.py)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nma import config
from nma.errors import ConfigError
from nma.mechanics.laws import (
    law_of,
    nominal_stress,
    principal_power_sum,
)
from nma.mechanics.material import Material
from nma.resolve import material_of, material_params
from nma.schema import MaterialConfig
from nma.simulator import Simulator

NU = 0.3
# one parameter set per law (stable over stretches [0.5, 2]), in the scene's units
CASES = {
    "mooney_rivlin": {"C10": 0.3, "C01": 0.08},
    "yeoh": {"C10": 0.3, "C20": 0.02, "C30": 0.004},
    "ogden": {"mu1": 0.5, "alpha1": 1.6, "mu2": -0.02, "alpha2": -3.0, "mu3": 0.001, "alpha3": 6.0},
    "gent": {"mu": 0.6, "Jm": 20.0},
    "arruda_boyce": {"mu": 0.3, "lambda_m": 3.0},
}
# Arruda-Boyce's series: psi = mu sum_i C_i / lambda_m^(2i - 2) (I1^i - 3^i) (Arruda and Boyce, J.
# Mech. Phys. Solids 41(2), 1993; Abaqus Theory Manual, hyperelastic material behaviour)
AB_SERIES = [1 / 2, 1 / 20, 11 / 1050, 19 / 7000, 519 / 673750]


def material(law, values, formulation="displacement"):
    cfg = MaterialConfig(law=law, E=None, parameters=values, nu=NU, formulation=formulation)
    cfg = dataclasses.replace(cfg, volumetric="bulk")  # the paper's kappa (kappa_of), as below
    return material_of(cfg), material_params(cfg)


def psi_derivatives(law, v, I1):
    """dpsi/dI1 and dpsi/dI2 of the invariant laws, by hand."""
    a = I1 - 3.0
    if law == "mooney_rivlin":
        return v["C10"], v["C01"]
    if law == "yeoh":
        return v["C10"] + 2 * v["C20"] * a + 3 * v["C30"] * a**2, 0.0
    if law == "gent":
        return 0.5 * v["mu"] / (1.0 - a / v["Jm"]), 0.0
    if law == "arruda_boyce":
        return v["mu"] * sum(
            i * c * I1 ** (i - 1) / v["lambda_m"] ** (2 * i - 2) for i, c in enumerate(AB_SERIES, 1)
        ), 0.0
    raise KeyError(law)


def stress_free_coefficient(law, v):
    """c0 of -c0 log J, by hand: dpsi/dlambda at rest (2 psi_1 + 4 psi_2, or sum mu_k)."""
    return {
        "mooney_rivlin": lambda: 2 * v["C10"] + 4 * v["C01"],
        "yeoh": lambda: 2 * v["C10"],
        "gent": lambda: v["mu"],
        "ogden": lambda: sum(v[f"mu{k}"] for k in (1, 2, 3)),
        "arruda_boyce": lambda: initial_shear(law, v),
    }[law]()


def kappa_of(mu0):
    return 2 * mu0 * (1 + NU) / (3 * (1 - 2 * NU))


def initial_shear(law, v):
    """mu0 by hand; Arruda-Boyce's is the Abaqus Theory Manual's closed form."""
    lm2 = v.get("lambda_m", 1.0) ** 2
    return {
        "mooney_rivlin": lambda: 2 * (v["C10"] + v["C01"]),
        "yeoh": lambda: 2 * v["C10"],
        "gent": lambda: v["mu"],
        "ogden": lambda: 0.5 * sum(v[f"mu{k}"] * v[f"alpha{k}"] for k in (1, 2, 3)),
        "arruda_boyce": lambda: (
            v["mu"]
            * (
                1
                + 3 / (5 * lm2)
                + 99 / (175 * lm2**2)
                + 513 / (875 * lm2**3)
                + 42039 / (67375 * lm2**4)
            )
        ),
    }[law]()


@pytest.mark.parametrize("law", sorted(CASES))
@pytest.mark.parametrize(
    "stretches",
    [(1.4, 1.0), (0.7, 1.0), (1.3, 1.3), (1.5, 1 / 1.5), (0.8, 1.25)],
    ids=["uniaxial", "uniaxial-compression", "equibiaxial", "pure-shear", "mixed"],
)
def test_principal_stress_of_a_homogeneous_deformation_is_the_closed_form(law, stretches):
    """F = diag(a, b) in plane strain (lambda_3 = 1): P_11 = dW/da by hand.  Invariant laws:
    I1 = a^2 + b^2 + 1, I2 = a^2 b^2 + a^2 + b^2, so P_11 = 2 a psi_1 + 2 a (b^2 + 1) psi_2 - c0 / a
    + kappa log(ab) / a; Ogden: P_11 = sum mu_k a^(alpha_k - 1) - c0 / a + kappa log(ab) / a."""
    v = CASES[law]
    model, p = material(law, v)
    a, b = stretches
    P = np.asarray(model.point_terms(p)[1](jnp.diag(jnp.array([a, b]))))
    kappa, c0, logJ = (
        kappa_of(initial_shear(law, v)),
        stress_free_coefficient(law, v),
        np.log(a * b),
    )
    expected = []
    for x, y in ((a, b), (b, a)):
        if law == "ogden":
            dev = sum(v[f"mu{k}"] * x ** (v[f"alpha{k}"] - 1) for k in (1, 2, 3))
        else:
            psi1, psi2 = psi_derivatives(law, v, a * a + b * b + 1)
            dev = 2 * x * psi1 + 2 * x * (y * y + 1) * psi2
        expected.append(dev - c0 / x + kappa * logJ / x)
    np.testing.assert_allclose(np.diag(P), expected, rtol=1e-12)
    assert abs(P[0, 1]) < 1e-14 and abs(P[1, 0]) < 1e-14


@pytest.mark.parametrize("law", sorted(CASES))
def test_simple_shear_stress_is_the_closed_form(law):
    """F = [[1, g], [0, 1]] (J = 1): P_12 = 2 (psi_1 + psi_2) g for the invariant laws (Rivlin's
    classic result), and for Ogden sum mu_k (l^alpha_k - l^-alpha_k) / (l + 1/l) with the principal
    stretch l = g/2 + sqrt(1 + g^2/4) (Ogden, Non-linear elastic deformations, sec. 7.2)."""
    v, g = CASES[law], 0.6
    model, p = material(law, v)
    P = np.asarray(model.point_terms(p)[1](jnp.array([[1.0, g], [0.0, 1.0]])))
    if law == "ogden":
        lam = g / 2 + np.sqrt(1 + g * g / 4)
        expected = sum(
            v[f"mu{k}"] * (lam ** v[f"alpha{k}"] - lam ** -v[f"alpha{k}"]) for k in (1, 2, 3)
        ) / (lam + 1 / lam)
    else:
        psi1, psi2 = psi_derivatives(law, v, 3 + g * g)
        expected = 2 * (psi1 + psi2) * g
    np.testing.assert_allclose(P[0, 1], expected, rtol=1e-12)


@pytest.mark.parametrize("law", sorted(CASES))
@pytest.mark.parametrize("volumetric", [True, False])
def test_stress_and_tangent_are_the_energys_derivatives(law, volumetric):
    """P against central differences of W, dP/dF against central differences of P, at a general F
    (step 1e-6: truncation ~1e-12, round-off ~1e-10 relative)."""
    model, p = material(law, CASES[law])
    W, P, C = model.point_terms(p, volumetric)
    F = jnp.array([[1.21, 0.17], [-0.08, 0.86]])
    h = 1e-6
    fd_P = np.zeros((2, 2))
    fd_C = np.zeros((2, 2, 2, 2))
    for k in range(2):
        for m in range(2):
            dF = jnp.zeros((2, 2)).at[k, m].set(h)
            fd_P[k, m] = (W(F + dF) - W(F - dF)) / (2 * h)
            fd_C[:, :, k, m] = (P(F + dF) - P(F - dF)) / (2 * h)
    np.testing.assert_allclose(P(F), fd_P, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(C(F), fd_C, rtol=1e-7, atol=1e-9)


def test_laws_that_reduce_to_neo_hookean_give_its_answers_to_round_off():
    """Mooney-Rivlin with C01 = 0 and C10 = mu/2, Yeoh with C20 = C30 = 0, one-term Ogden with alpha
    = 2 are Neo-Hookean of shear modulus mu: W, P and dP/dF at random F (equal stretches included)
    to round-off."""
    E = 0.07
    mu = E / (2 * (1 + NU))
    nh = Material()
    ref = nh.point_terms(jnp.array([E, NU]))
    rng = np.random.default_rng(1)
    Fs = jnp.asarray(np.eye(2) + 0.3 * rng.standard_normal((20, 2, 2)))
    Fs = Fs.at[0].set(1.2 * jnp.eye(2)).at[1].set(jnp.eye(2))
    Fs = Fs[np.asarray(jax.vmap(jnp.linalg.det)(Fs)) > 0.2]
    for law, v in (
        ("mooney_rivlin", {"C10": mu / 2, "C01": 0.0}),
        ("yeoh", {"C10": mu / 2, "C20": 0.0, "C30": 0.0}),
        ("ogden", {"mu1": mu, "alpha1": 2.0}),
    ):
        model, p = material(law, v)
        got = model.point_terms(p)
        for r, g in zip(ref, got):
            np.testing.assert_allclose(g(Fs), r(Fs), rtol=1e-13, atol=1e-15, err_msg=law)


def test_ogdens_eigenvalue_sum_is_smooth_across_equal_stretches():
    """c1^b + c2^b of C: the series (x^2 < 0.01) and the closed form agree where they meet, and the
    derivative at C = s I (equal eigenvalues, where the closed form's sqrt has none) is b s^(b-1)
    I."""
    b = 1.7
    for x2 in (0.0099999, 0.0100001):
        m, x = 1.3, np.sqrt(x2)
        C = jnp.diag(jnp.array([m * (1 + x), m * (1 - x)]))
        np.testing.assert_allclose(
            principal_power_sum(C, b), (m * (1 + x)) ** b + (m * (1 - x)) ** b, rtol=1e-14
        )
    g = jax.grad(lambda C: principal_power_sum(C, b))(1.3 * jnp.eye(2))
    np.testing.assert_allclose(g, b * 1.3 ** (b - 1) * np.eye(2), rtol=1e-13, atol=1e-15)


def test_nominal_stress_is_the_incompressible_closed_form():
    """Mooney-Rivlin: uniaxial P = 2 (l - l^-2)(C10 + C01 / l), equibiaxial P = 2 (l - l^-5)(C10 +
    C01 l^2), planar P = 2 (l - l^-3)(C10 + C01) (Treloar; e.g. Ogden, Non-linear elastic
    deformations, sec. 7.2)."""
    C10, C01 = 0.3, 0.08
    law = law_of("mooney_rivlin")
    lam = np.linspace(0.6, 2.5, 9)
    p = jnp.array([C10, C01])
    np.testing.assert_allclose(
        nominal_stress(law, p, "uniaxial", lam), 2 * (lam - lam**-2) * (C10 + C01 / lam), rtol=1e-12
    )
    np.testing.assert_allclose(
        nominal_stress(law, p, "biaxial", lam),
        2 * (lam - lam**-5) * (C10 + C01 * lam**2),
        rtol=1e-12,
    )
    np.testing.assert_allclose(
        nominal_stress(law, p, "planar", lam), 2 * (lam - lam**-3) * (C10 + C01), rtol=1e-12
    )


@pytest.fixture(scope="module")
def strip_yeoh():
    """The tutorial's strip scene at 5 x 3 with the Yeoh case, Newton to 1e-12 (central
    differences)."""
    return Simulator.from_config(
        "strip",
        {"ctrl_per_patch": 5, "quad_points": 3},
        {"linear": "pardiso", "rtol": 1e-12},
        material={"law": "yeoh", "E": None, "parameters": CASES["yeoh"], "nu": NU},
    )


def test_a_solves_gradient_in_the_laws_parameters_matches_central_differences(strip_yeoh):
    """d(tracked displacement)/d(C10, C20, C30, nu) by the implicit adjoint against central
    differences of converged solves (step 1e-6 relative; Newton to 1e-12)."""
    sim = strip_yeoh
    X = sim.reference_points(sim.init_params())
    d = jnp.array([1.5, 1.0])
    mat = sim.material_params

    def out(m):
        u = sim.equilibrium(X, d, m).u
        return jnp.sum(sim.tracked(X, u)["top_left"] ** 2)

    g = np.asarray(jax.grad(out)(mat))
    for k in range(len(mat)):
        h = 1e-6 * abs(float(mat[k]))
        fd = (out(mat.at[k].add(h)) - out(mat.at[k].add(-h))) / (2 * h)
        np.testing.assert_allclose(
            g[k], fd, rtol=1e-5, atol=1e-9 * abs(float(out(mat))) / abs(float(mat[k]))
        )


def test_every_shipped_material_file_is_a_checked_material():
    """conf/material/: each file builds a MaterialConfig (ranges, shear modulus, Drucker
    stability)."""
    for name in config.options("material"):
        cfg = MaterialConfig(**{k: v for k, v in config.load("material", name).items()})
        assert material_params(cfg).shape == (len(law_of(cfg.law, cfg.values).names) + 1,)
        mixed = dataclasses.replace(cfg, formulation="mixed")
        if law_of(cfg.law).volume_term:
            assert material_of(mixed).mixed
        else:  # a whole energy (St Venant-Kirchhoff) has no volume term to take per element
            with pytest.raises(ConfigError, match="formulation=mixed .* has none"):
                material_of(mixed)


def test_principal_stretches_of_a_rotated_stretch():
    """F = R diag(1.5, 0.8) and diag(1.5, 0.8) R (rotation R by 0.7 rad) have principal stretches
    0.8 and 1.5; simple shear g = 0.6 has l = g/2 + sqrt(1 + g^2/4) and 1/l."""
    from nma.mechanics.laws import principal_stretch_range

    c, s = np.cos(0.7), np.sin(0.7)
    R, U = np.array([[c, -s], [s, c]]), np.diag([1.5, 0.8])
    np.testing.assert_allclose(
        principal_stretch_range(jnp.asarray(np.stack([R @ U, U @ R]))), (0.8, 1.5), rtol=1e-14
    )
    lam = 0.3 + np.sqrt(1.09)
    np.testing.assert_allclose(
        principal_stretch_range(jnp.array([[1.0, 0.6], [0.0, 1.0]])), (1 / lam, lam), rtol=1e-14
    )


@pytest.mark.parametrize("law", sorted(CASES))
def test_stress_is_differentiable_in_every_parameter(law):
    """d(P(F) : G)/d(parameters, nu) by JAX against central differences (step 1e-6 relative): what
    the adjoint of a solve takes (test_a_solves_gradient_... checks one law through a whole
    solve)."""
    model, p = material(law, CASES[law])
    F, G = jnp.array([[1.3, 0.2], [-0.1, 0.9]]), jnp.array([[0.3, -0.7], [0.5, 1.1]])
    f = lambda q: jnp.sum(model.point_terms(q)[1](F) * G)
    g = np.asarray(jax.grad(f)(p))
    for k in range(len(p)):
        h = 1e-6 * abs(float(p[k]))
        fd = (f(p.at[k].add(h)) - f(p.at[k].add(-h))) / (2 * h)
        np.testing.assert_allclose(g[k], fd, rtol=1e-6, atol=1e-10)


# slow: two scenes built and solved to 1e-12 (the laws' reduction point by point: a fast test)
@pytest.mark.slow
def test_a_solve_in_a_law_that_reduces_to_neo_hookean_is_neo_hookeans():
    """The strip in the locking-free (mixed) formulation at nu 0.45: Mooney-Rivlin with C10 = mu/2,
    C01 = 0 reaches Neo-Hookean's equilibrium (closed-form stress and tangent) to round-off: the
    laws share the volumetric treatment."""
    E, nu = 0.07, 0.45
    mu = E / (2 * (1 + nu))
    fidelity = {"ctrl_per_patch": 5, "quad_points": 3}
    solver = {"linear": "pardiso", "rtol": 1e-12}
    nh = Simulator.from_config(
        "strip", fidelity, solver, material={"E": E, "nu": nu, "formulation": "mixed"}
    )
    mr = Simulator.from_config(
        "strip",
        fidelity,
        solver,
        material={
            "law": "mooney_rivlin",
            "E": None,
            "parameters": {"C10": mu / 2, "C01": 0.0},
            "nu": nu,
            "formulation": "mixed",
        },
    )
    d = jnp.array([2.0, 1.0])
    u_nh = nh.solve(nh.init_params(), d, nh.material_params).u
    u_mr = mr.solve(mr.init_params(), d, mr.material_params).u
    assert float(jnp.max(jnp.abs(u_nh))) > 0.5  # a large deformation
    np.testing.assert_allclose(u_mr, u_nh, rtol=0, atol=1e-10 * float(jnp.max(jnp.abs(u_nh))))


# -- Arruda-Boyce ---------------------------------------------------------------------------------


def inverse_langevin(y):
    """L^-1(y), L(x) = coth x - 1/x, by bisection to round-off (0 < y < 1)."""
    lo, hi = np.full_like(y, 1e-9), np.full_like(y, 1e3)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        below = 1 / np.tanh(mid) - 1 / mid < y
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return 0.5 * (lo + hi)


def test_arruda_boyce_uniaxial_stress_is_the_eight_chain_closed_form():
    """Uniaxial nominal stress P = 2 (l - l^-2) dpsi/dI1, I1 = l^2 + 2/l: the series' dpsi/dI1 by
    hand to round-off, and the exact eight-chain model's, (mu / 6) (lambda_m / lambda_ch)
    L^-1(lambda_ch / lambda_m), lambda_ch = sqrt(I1 / 3) (Arruda and Boyce 1993), within
    the series' truncation (below 0.2% where lambda_ch / lambda_m <= 0.5)."""
    v = {"mu": 0.25, "lambda_m": 4.0}
    lam = np.linspace(0.5, 3.2, 12)
    P = np.asarray(
        nominal_stress(law_of("arruda_boyce"), [v["mu"], v["lambda_m"]], "uniaxial", lam)
    )
    I1 = lam**2 + 2 / lam
    np.testing.assert_allclose(
        P, 2 * (lam - lam**-2) * psi_derivatives("arruda_boyce", v, I1)[0], rtol=1e-12
    )
    x = np.sqrt(I1 / 3) / v["lambda_m"]
    assert x.max() < 0.5
    exact = 2 * (lam - lam**-2) * v["mu"] / 6 * inverse_langevin(x) / x
    np.testing.assert_allclose(P, exact, rtol=2e-3)


def test_arruda_boyces_small_strain_shear_modulus_is_the_series_mu0():
    """Simple shear g -> 0: P_12 / g is mu0 = mu (1 + 3/(5 lm^2) + ...) (Abaqus' closed form), which
    tends to mu as lambda_m grows (the Gaussian chain: Neo-Hookean of modulus mu)."""
    for lm in (2.0, 7.0, 1e4):
        v = {"mu": 0.3, "lambda_m": lm}
        model, p = material("arruda_boyce", v)
        g = 1e-7
        P12 = float(model.point_terms(p)[1](jnp.array([[1.0, g], [0.0, 1.0]]))[0, 1])
        np.testing.assert_allclose(P12 / g, initial_shear("arruda_boyce", v), rtol=1e-7)
        np.testing.assert_allclose(
            float(model.moduli(p)[0]), initial_shear("arruda_boyce", v), rtol=1e-14
        )
    assert abs(initial_shear("arruda_boyce", v) / 0.3 - 1) < 1e-8


def test_a_scene_solves_in_arruda_boyce_from_its_material_file():
    """`material=arruda_boyce` (its generated file): translation at 5 x 3 converges at three
    actuations, each displacing the part further than the last."""
    sim = Simulator.from_config(
        "translation",
        {"ctrl_per_patch": 5, "quad_points": 3},
        {"linear": "pardiso"},
        material="arruda_boyce",
    )
    assert sim.disc.material.law.name == "arruda_boyce" and sim.material_params.shape == (3,)
    params, moved = sim.init_params(), []
    for s in (0.5, 1.0, 2.0):
        sol = sim.solve(params, jnp.array([s, -s]), sim.material_params, throw=False)
        assert bool(sol.converged), (s, sol.message)
        moved.append(float(jnp.max(jnp.abs(sol.u))))
    assert 0 < moved[0] < moved[1] < moved[2]
