"""The hyperelastic laws (nma.mechanics.laws, nma.mechanics.material.Material): stresses of homogeneous
deformations against closed forms written out here by hand, derivatives against central differences,
Neo-Hookean's special cases, Drucker stability, and a solve's gradient with respect to the parameters."""
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nma import config
from nma.errors import ConfigError
from nma.mechanics.laws import drucker_unstable, law_of, nominal_stress, principal_power_sum
from nma.mechanics.material import Material, from_lame, lame
from nma.mechanics.material import material as mat_of
from nma.schema import MaterialConfig
from nma.simulator import Simulator

NU = 0.3
# one parameter set per law (stable over stretches [0.5, 2]), in the scene's units
CASES = {
    "mooney_rivlin": {"C10": 0.3, "C01": 0.08},
    "yeoh": {"C10": 0.3, "C20": 0.02, "C30": 0.004},
    "ogden": {"mu1": 0.5, "alpha1": 1.6, "mu2": -0.02, "alpha2": -3.0, "mu3": 0.001, "alpha3": 6.0},
    "gent": {"mu": 0.6, "Jm": 20.0},
}


def material(law, values, formulation="displacement"):
    cfg = MaterialConfig(law=law, E=None, parameters=values, nu=NU, formulation=formulation)
    return cfg.model(), cfg.params()


def psi_derivatives(law, v, I1):
    """dpsi/dI1 and dpsi/dI2 of the invariant laws, by hand."""
    a = I1 - 3.0
    if law == "mooney_rivlin":
        return v["C10"], v["C01"]
    if law == "yeoh":
        return v["C10"] + 2 * v["C20"] * a + 3 * v["C30"] * a ** 2, 0.0
    if law == "gent":
        return 0.5 * v["mu"] / (1.0 - a / v["Jm"]), 0.0
    raise KeyError(law)


def stress_free_coefficient(law, v):
    """c0 of -c0 log J, by hand: dpsi/dlambda at rest (2 psi_1 + 4 psi_2, or sum mu_k)."""
    return {"mooney_rivlin": lambda: 2 * v["C10"] + 4 * v["C01"], "yeoh": lambda: 2 * v["C10"], "gent": lambda: v["mu"],
            "ogden": lambda: sum(v[f"mu{k}"] for k in (1, 2, 3))}[law]()


def kappa_of(mu0):
    return 2 * mu0 * (1 + NU) / (3 * (1 - 2 * NU))


def initial_shear(law, v):
    return {"mooney_rivlin": lambda: 2 * (v["C10"] + v["C01"]), "yeoh": lambda: 2 * v["C10"], "gent": lambda: v["mu"],
            "ogden": lambda: 0.5 * sum(v[f"mu{k}"] * v[f"alpha{k}"] for k in (1, 2, 3))}[law]()


@pytest.mark.parametrize("law", sorted(CASES))
@pytest.mark.parametrize("stretches", [(1.4, 1.0), (0.7, 1.0), (1.3, 1.3), (1.5, 1 / 1.5), (0.8, 1.25)],
                         ids=["uniaxial", "uniaxial-compression", "equibiaxial", "pure-shear", "mixed"])
def test_principal_stress_of_a_homogeneous_deformation_is_the_closed_form(law, stretches):
    """F = diag(a, b) in plane strain (lambda_3 = 1): P_11 = dW/da by hand.  Invariant laws:
    I1 = a^2 + b^2 + 1, I2 = a^2 b^2 + a^2 + b^2, so P_11 = 2 a psi_1 + 2 a (b^2 + 1) psi_2 - c0 / a
    + kappa log(ab) / a; Ogden: P_11 = sum mu_k a^(alpha_k - 1) - c0 / a + kappa log(ab) / a."""
    v = CASES[law]
    model, p = material(law, v)
    a, b = stretches
    P = np.asarray(model.point_terms(p)[1](jnp.diag(jnp.array([a, b]))))
    kappa, c0, logJ = kappa_of(initial_shear(law, v)), stress_free_coefficient(law, v), np.log(a * b)
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
    """F = [[1, g], [0, 1]] (J = 1): P_12 = 2 (psi_1 + psi_2) g for the invariant laws (Rivlin's classic
    result), and for Ogden sum mu_k (l^alpha_k - l^-alpha_k) / (l + 1/l) with the principal stretch
    l = g/2 + sqrt(1 + g^2/4) (Ogden, Non-linear elastic deformations, sec. 7.2)."""
    v, g = CASES[law], 0.6
    model, p = material(law, v)
    P = np.asarray(model.point_terms(p)[1](jnp.array([[1.0, g], [0.0, 1.0]])))
    if law == "ogden":
        lam = g / 2 + np.sqrt(1 + g * g / 4)
        expected = sum(v[f"mu{k}"] * (lam ** v[f"alpha{k}"] - lam ** -v[f"alpha{k}"]) for k in (1, 2, 3)) / (lam + 1 / lam)
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
    """Mooney-Rivlin with C01 = 0 and C10 = mu/2, Yeoh with C20 = C30 = 0, one-term Ogden with alpha = 2 are
    Neo-Hookean of shear modulus mu: W, P and dP/dF at random F (equal stretches included) to round-off."""
    E = 0.07
    mu = float(lame(jnp.array([E, NU]))[0])
    nh = Material()
    ref = nh.point_terms(jnp.array([E, NU]))
    rng = np.random.default_rng(1)
    Fs = jnp.asarray(np.eye(2) + 0.3 * rng.standard_normal((20, 2, 2)))
    Fs = Fs.at[0].set(1.2 * jnp.eye(2)).at[1].set(jnp.eye(2))
    Fs = Fs[np.asarray(jax.vmap(jnp.linalg.det)(Fs)) > 0.2]
    for law, v in (("mooney_rivlin", {"C10": mu / 2, "C01": 0.0}), ("yeoh", {"C10": mu / 2, "C20": 0.0, "C30": 0.0}),
                   ("ogden", {"mu1": mu, "alpha1": 2.0})):
        model, p = material(law, v)
        got = model.point_terms(p)
        for r, g in zip(ref, got):
            np.testing.assert_allclose(g(Fs), r(Fs), rtol=1e-13, atol=1e-15, err_msg=law)


def test_ogdens_eigenvalue_sum_is_smooth_across_equal_stretches():
    """c1^b + c2^b of C: the series (x^2 < 0.01) and the closed form agree where they meet, and the
    derivative at C = s I (equal eigenvalues, where the closed form's sqrt has none) is b s^(b-1) I."""
    b = 1.7
    for x2 in (0.0099999, 0.0100001):
        m, x = 1.3, np.sqrt(x2)
        C = jnp.diag(jnp.array([m * (1 + x), m * (1 - x)]))
        np.testing.assert_allclose(principal_power_sum(C, b), (m * (1 + x)) ** b + (m * (1 - x)) ** b, rtol=1e-14)
    g = jax.grad(lambda C: principal_power_sum(C, b))(1.3 * jnp.eye(2))
    np.testing.assert_allclose(g, b * 1.3 ** (b - 1) * np.eye(2), rtol=1e-13, atol=1e-15)


def test_nominal_stress_is_the_incompressible_closed_form():
    """Mooney-Rivlin: uniaxial P = 2 (l - l^-2)(C10 + C01 / l), equibiaxial P = 2 (l - l^-5)(C10 + C01 l^2),
    planar P = 2 (l - l^-3)(C10 + C01) (Treloar; e.g. Ogden, Non-linear elastic deformations, sec. 7.2)."""
    C10, C01 = 0.3, 0.08
    law = law_of("mooney_rivlin")
    lam = np.linspace(0.6, 2.5, 9)
    p = jnp.array([C10, C01])
    np.testing.assert_allclose(nominal_stress(law, p, "uniaxial", lam), 2 * (lam - lam ** -2) * (C10 + C01 / lam), rtol=1e-12)
    np.testing.assert_allclose(nominal_stress(law, p, "biaxial", lam), 2 * (lam - lam ** -5) * (C10 + C01 * lam ** 2),
                               rtol=1e-12)
    np.testing.assert_allclose(nominal_stress(law, p, "planar", lam), 2 * (lam - lam ** -3) * (C10 + C01), rtol=1e-12)


@pytest.mark.parametrize("law, values, says", [
    ("yeoh", {"C10": 0.1, "C20": -0.05, "C30": 0.0}, "not stable (Drucker) for principal stretches in "
                                                     "material.stretches=[0.5, 2.0]: uniaxial tension at stretch 0.5"),
    ("gent", {"mu": 0.1, "Jm": 5.0}, "beyond the law's limit"),
    ("mooney_rivlin", {"C10": 0.1, "C01": -0.2}, "initial shear modulus -0.2: it must be positive"),
    ("ogden", {"mu1": 0.1, "alpha1": 0.0}, "material.parameters.alpha1 must lie in [-100, -0.01] or [0.01, 100]"),
    ("ogden", {"mu1": 0.1}, "material.parameters.alpha1 is missing"),
    ("yeoh", {"C10": 0.1, "C20": 0.0, "C30": 0.0, "C40": 1.0}, "['C40'] are not law yeoh's"),
])
def test_unstable_or_malformed_parameters_are_refused_naming_the_range(law, values, says):
    with pytest.raises(ConfigError, match=None) as err:
        MaterialConfig(law=law, E=None, parameters=values)
    assert says in str(err.value)


def test_a_law_takes_its_own_parameters_not_neo_hookeans():
    with pytest.raises(ConfigError, match="material.E is Neo-Hookean's; law gent takes material.parameters"):
        MaterialConfig(law="gent", parameters={"mu": 0.1, "Jm": 50.0})
    with pytest.raises(ConfigError, match="material.parameters are the other laws'"):
        MaterialConfig(parameters={"mu": 0.1})


@pytest.fixture(scope="module")
def strip_yeoh():
    """The tutorial's strip scene at 5 x 3 with the Yeoh case, Newton to 1e-12 (central differences)."""
    return Simulator.from_config("strip", {"ctrl_per_patch": 5, "quad_points": 3}, {"linear": "pardiso", "rtol": 1e-12},
                                 material={"law": "yeoh", "E": None, "parameters": CASES["yeoh"], "nu": NU})


def test_a_solves_gradient_in_the_laws_parameters_matches_central_differences(strip_yeoh):
    """d(tracked displacement)/d(C10, C20, C30, nu) by the implicit adjoint against central differences
    of converged solves (step 1e-6 relative; Newton to 1e-12)."""
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
        np.testing.assert_allclose(g[k], fd, rtol=1e-5, atol=1e-9 * abs(float(out(mat))) / abs(float(mat[k])))


def test_every_shipped_material_file_is_a_checked_material():
    """conf/material/: each file builds a MaterialConfig (ranges, shear modulus, Drucker stability)."""
    for name in config.options("material"):
        cfg = MaterialConfig(**{k: v for k, v in config.load("material", name).items()})
        assert cfg.params().shape == (len(law_of(cfg.law, cfg.values).names) + 1,)
        assert dataclasses.replace(cfg, formulation="mixed").model().mixed


def test_principal_stretches_of_a_rotated_stretch():
    """F = R diag(1.5, 0.8) and diag(1.5, 0.8) R (rotation R by 0.7 rad) have principal stretches 0.8 and 1.5;
    simple shear g = 0.6 has l = g/2 + sqrt(1 + g^2/4) and 1/l."""
    from nma.mechanics.laws import principal_stretch_range

    c, s = np.cos(0.7), np.sin(0.7)
    R, U = np.array([[c, -s], [s, c]]), np.diag([1.5, 0.8])
    np.testing.assert_allclose(principal_stretch_range(jnp.asarray(np.stack([R @ U, U @ R]))), (0.8, 1.5), rtol=1e-14)
    lam = 0.3 + np.sqrt(1.09)
    np.testing.assert_allclose(principal_stretch_range(jnp.array([[1.0, 0.6], [0.0, 1.0]])), (1 / lam, lam), rtol=1e-14)


@pytest.mark.parametrize("law", sorted(CASES))
def test_stress_is_differentiable_in_every_parameter(law):
    """d(P(F) : G)/d(parameters, nu) by JAX against central differences (step 1e-6 relative): what the
    adjoint of a solve takes (test_a_solves_gradient_... checks one law through a whole solve)."""
    model, p = material(law, CASES[law])
    F, G = jnp.array([[1.3, 0.2], [-0.1, 0.9]]), jnp.array([[0.3, -0.7], [0.5, 1.1]])
    f = lambda q: jnp.sum(model.point_terms(q)[1](F) * G)  # noqa: E731
    g = np.asarray(jax.grad(f)(p))
    for k in range(len(p)):
        h = 1e-6 * abs(float(p[k]))
        fd = (f(p.at[k].add(h)) - f(p.at[k].add(-h))) / (2 * h)
        np.testing.assert_allclose(g[k], fd, rtol=1e-6, atol=1e-10)


@pytest.mark.slow  # two scenes built and solved to 1e-12; the laws' reduction point by point is a fast test above
def test_a_solve_in_a_law_that_reduces_to_neo_hookean_is_neo_hookeans():
    """The strip in the locking-free (mixed) formulation at nu 0.45: Mooney-Rivlin with C10 = mu/2, C01 = 0
    reaches Neo-Hookean's equilibrium (closed-form stress and tangent) to round-off: the laws share the
    volumetric treatment."""
    E, nu = 0.07, 0.45
    mu = float(lame(jnp.array([E, nu]))[0])
    fidelity, solver = {"ctrl_per_patch": 5, "quad_points": 3}, {"linear": "pardiso", "rtol": 1e-12}
    nh = Simulator.from_config("strip", fidelity, solver, material={"E": E, "nu": nu, "formulation": "mixed"})
    mr = Simulator.from_config("strip", fidelity, solver, material={
        "law": "mooney_rivlin", "E": None, "parameters": {"C10": mu / 2, "C01": 0.0}, "nu": nu, "formulation": "mixed"})
    d = jnp.array([2.0, 1.0])
    u_nh = nh.solve(nh.init_params(), d, nh.material_params).u
    u_mr = mr.solve(mr.init_params(), d, mr.material_params).u
    assert float(jnp.max(jnp.abs(u_nh))) > 0.5  # a large deformation
    np.testing.assert_allclose(u_mr, u_nh, rtol=0, atol=1e-10 * float(jnp.max(jnp.abs(u_nh))))



@pytest.mark.parametrize("law, p, says", [
    ("gent", [0.1], "p must hold 2 parameters, got 1: law gent takes [mu, Jm]"),
    ("gent", [0.1, 5.0, 3.0], "p must hold 2 parameters, got 3: law gent takes [mu, Jm]"),
    ("yeoh", [0.1], "p must hold 3 parameters, got 1: law yeoh takes [C10, C20, C30]"),
    ("mooney_rivlin", [[0.1, 0.0]], "p must have shape (n,), got (1, 2); law mooney_rivlin takes"),
    ("gent", [np.nan, 5.0], "p must be finite, got [nan, 5.0]; law gent takes [mu, Jm]"),
    ("gent", [0.1, -5.0], "p = [mu, Jm] must have Jm in (0, 1e12] (law gent), got -5"),
    ("ogden", [0.1, 0.0], "law ogden1's exponents alpha must lie in [-100, -0.01] or [0.01, 100]"),
])
def test_a_laws_stress_refuses_parameters_not_the_laws(law, p, says):
    """Too few, too many, not finite or out of range: refused naming the law and what it takes,
    not a plausible number from the parameters that are there."""
    names = ("mu1", "alpha1") if law == "ogden" else ()
    with pytest.raises(ConfigError) as err:
        nominal_stress(law_of(law, names), jnp.asarray(p), "uniaxial", 1.5)
    assert f"nominal_stress: {says}" in str(err.value)


def test_the_laws_functions_check_their_other_arguments_naming_them():
    gent, p, nh = law_of("gent"), jnp.array([0.1, 5.0]), law_of("neo_hookean")
    cases = [(lambda: nominal_stress(gent, p, "shear", 1.5), ConfigError,
              "nominal_stress: mode must be one of"),
             (lambda: nominal_stress(gent, p, "uniaxial", -1.5), ConfigError,
              "nominal_stress: lam must hold positive"),
             (lambda: nominal_stress("gent", p, "uniaxial", 1.5), TypeError,
              "nominal_stress: law must be a Law"),
             (lambda: nominal_stress(nh, jnp.array([1.0]), "uniaxial", 1.5), ConfigError,
              "law neo_hookean is parametrised by E and nu"),
             (lambda: drucker_unstable(law_of("yeoh"), jnp.array([0.1])), ConfigError,
              "drucker_unstable: p must hold 3 parameters, got 1: law yeoh takes [C10, C20, C30]"),
             (lambda: drucker_unstable(gent, p, (2.0, 0.5)), ConfigError,
              "drucker_unstable: stretches must be (low, high) with 0 < low < high"),
             (lambda: Material(law=gent).check(jnp.array([0.1, 5.0])), ValueError,
              "equilibrium: mat must be law gent's [mu, Jm, nu]: 3 numbers, got 2"),
             (lambda: from_lame(-1.0, 2.0), ValueError, "from_lame: mu must be a finite number"),
             (lambda: mat_of("stiff", 0.3), TypeError, "material: E must be a real number")]
    for call, kind, says in cases:
        with pytest.raises(kind) as err:
            call()
        assert says in str(err.value)
