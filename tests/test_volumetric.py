"""What nu means (material.volumetric): the volume term k/2 (log J)^2 with k the 3D bulk modulus
kappa = E / (3 (1 - 2 nu)) (`bulk`, the paper's form) or the Lame constant of the law's 3D
compressible form (`lame`), against closed forms.

Plane strain of an isotropic solid of Lame constants (l, mu) under uniaxial stress in the plane
(sigma_22 = 0): eps_22 = -l / (l + 2 mu) eps_11, so the in-plane Poisson's ratio is l / (l + 2 mu)
and the plane modulus (l + 2 mu) - l^2 / (l + 2 mu) = 4 mu (l + mu) / (l + 2 mu).  With the 3D
Lame constant l = 2 mu nu / (1 - 2 nu) these are nu / (1 - nu) and E / (1 - nu^2) (any elasticity
text, e.g. Timoshenko and Goodier, Theory of Elasticity, sec. 17); with l = kappa (the paper's
form) they are kappa / (kappa + 2 mu) and 4 mu (kappa + mu) / (kappa + 2 mu): 0.52 and
1.064 E / (1 - nu^2) at nu = 0.3.
"""

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import brentq, minimize_scalar

from nma import config
from nma.discretise import discretise
from nma.errors import ConfigError
from nma.mechanics.energy import energy_force_tangents, quadrature, strain_energy
from nma.mechanics.laws import law_of
from nma.mechanics.material import Material, plane_strain_record
from nma.resolve import library_settings, material_of
from nma.schema import Fidelity, MaterialConfig, scene_from_config

E = 0.07
BLOCK = {
    "name": "block",
    "cell_size": 5.0,
    "cells": "SS\nSS",
    "supports": [{"segment": [[0, 0], [0, 10]], "kind": "clamped"}],
}


def lame_lambda(E, nu):
    return E * nu / ((1 + nu) * (1 - 2 * nu))


def neo_hookean(volumetric):
    return Material(law=law_of("neo_hookean"), volumetric=volumetric)


@pytest.mark.parametrize("nu", [0.0, 0.3, 0.45, 0.499])
def test_lame_form_gives_plane_strain_modulus_and_poisson_ratio(nu):
    """lame: E' = E / (1 - nu^2), nu' = nu / (1 - nu), G = mu (the module's closed forms)."""
    p = jnp.array([E, nu])
    plane, poisson, shear = (float(x) for x in neo_hookean("lame").plane_moduli(p))
    assert plane == pytest.approx(E / (1 - nu**2), rel=1e-12)
    assert poisson == pytest.approx(nu / (1 - nu), rel=1e-12, abs=1e-15)
    assert shear == pytest.approx(E / (2 * (1 + nu)), rel=1e-12)


@pytest.mark.parametrize("nu", [0.0, 0.3, 0.45])
def test_bulk_form_gives_the_lame_constants_kappa_and_mu(nu):
    """bulk: nu' = kappa / (kappa + 2 mu), E' = 4 mu (kappa + mu) / (kappa + 2 mu); at nu = 0.3
    0.52 and 1.064 E / (1 - nu^2) (the module's closed forms)."""
    mu, kappa = E / (2 * (1 + nu)), E / (3 * (1 - 2 * nu))
    plane, poisson, _ = (float(x) for x in neo_hookean("bulk").plane_moduli(jnp.array([E, nu])))
    assert poisson == pytest.approx(kappa / (kappa + 2 * mu), rel=1e-12)
    assert plane == pytest.approx(4 * mu * (kappa + mu) / (kappa + 2 * mu), rel=1e-12)
    if nu == 0.3:
        assert poisson == pytest.approx(0.52, rel=1e-12)
        assert plane / (E / (1 - nu**2)) == pytest.approx(1.064, rel=1e-12)


@pytest.mark.parametrize("law", ["neo_hookean", "mooney_rivlin", "yeoh", "ogden", "gent"])
@pytest.mark.parametrize("volumetric", ["bulk", "lame"])
@pytest.mark.parametrize("off", [0.0, 1e-9])
def test_plane_moduli_are_the_tangent_at_rest(law, volumetric, off):
    """plane_moduli (second derivatives in the principal stretches) equals the tangent dP/dF at
    F = I and within 1e-9 of it: C_1111 - C_1122^2 / C_2222, C_1122 / C_2222 and C_1212.  Equal
    stretches are where a law of the eigenvalues of the 2 x 2 C (Ogden) needs care."""
    model = Material(law=law_of(law), volumetric=volumetric)
    p = jnp.array([*law_of(law).defaults().values(), 0.3])
    F = jnp.eye(2) + off * jnp.array([[0.3, 0.1], [0.2, -0.4]])
    C = np.asarray(model.point_terms(p)[2](F))
    expected = (
        C[0, 0, 0, 0] - C[0, 0, 1, 1] ** 2 / C[1, 1, 1, 1],
        C[0, 0, 1, 1] / C[1, 1, 1, 1],
        C[0, 1, 0, 1],
    )
    np.testing.assert_allclose(model.plane_moduli(p), expected, rtol=1e-7 if off else 1e-12)


# (law, parameters, psi's own share of the Lame constant at rest: d2 psi(a, b, 1) / da db)
LAWS = [
    ("neo_hookean", [E], 0.0),
    # I2 = a^2 b^2 + a^2 + b^2 at c = 1: 4 C01
    ("mooney_rivlin", [0.0108, 0.0027], 4 * 0.0027),
    # a sum of powers of each stretch alone: none
    ("ogden", [0.02447, 2.0, -0.002447, -2.0], 0.0),
]


@pytest.mark.parametrize("law, values, own", LAWS, ids=[x[0] for x in LAWS])
def test_chosen_coefficient_enters_the_tangent_at_rest(law, values, own):
    """C_1122 at rest is the volume coefficient plus psi's own share: kappa + own (bulk) or the 3D
    Lame constant 2 mu0 nu / (1 - 2 nu) (lame, whatever psi), and C_1111 - C_1122 = 2 mu0 in both;
    so lame gives every law nu / (1 - nu) and E / (1 - nu^2), E = 2 mu0 (1 + nu).  The second
    derivatives are taken in the principal stretches (plane_moduli)."""
    nu = 0.3
    p = jnp.array([*values, nu])
    for volumetric in ("bulk", "lame"):
        model = Material(law=law_of(law), volumetric=volumetric)
        mu0, kappa = (float(x) for x in model.moduli(p))
        plane, poisson, shear = (float(x) for x in model.plane_moduli(p))
        c1111 = plane / (1 - poisson**2)  # C_1111 of E' and nu' (C_1111 = C_2222)
        c1122 = poisson * c1111
        k = kappa if volumetric == "bulk" else 2 * mu0 * nu / (1 - 2 * nu) - own
        assert float(model.volume_modulus(p)) == pytest.approx(k, rel=1e-12)
        assert c1122 == pytest.approx(k + own, rel=1e-12)
        assert c1111 - c1122 == pytest.approx(2 * mu0, rel=1e-11)
        assert shear == pytest.approx(mu0, rel=1e-12)
        if volumetric == "lame":
            assert poisson == pytest.approx(nu / (1 - nu), rel=1e-12)
            assert plane == pytest.approx(2 * mu0 * (1 + nu) / (1 - nu**2), rel=1e-12)


def uniaxial_lateral_stretch(l1, mu, lam):
    """The closed form's lateral stretch: P_22 = mu (l2 - 1 / l2) + lam log(l1 l2) / l2 = 0, i.e.
    mu (l2^2 - 1) + lam log(l1 l2) = 0, increasing in l2 (one root in (0, 2])."""
    return brentq(lambda l2: mu * (l2**2 - 1) + lam * np.log(l1 * l2), 1e-6, 2.0, xtol=1e-15)


@pytest.mark.parametrize("l1", [0.6, 0.8, 1.5, 2.2])
def test_neo_hookean_lame_uniaxial_plane_strain_stress_at_large_strain(l1):
    """Neo-Hookean in the lame form, F = diag(l1, l2) with P_22 = 0: W = mu/2 (l1^2 + l2^2 - 2)
    - mu log J + lam/2 (log J)^2, lam = E nu / ((1 + nu) (1 - 2 nu)); P_11 = mu (l1 - 1 / l1)
    + lam log J / l1 at the root l2 of P_22 (derived here).  nma's stress (closed form and automatic
    differentiation alike) vanishes across and matches P_11; the lateral stretch also minimises
    nma's own energy over l2 (scipy)."""
    nu = 0.3
    mu, lam = E / (2 * (1 + nu)), lame_lambda(E, nu)
    l2 = uniaxial_lateral_stretch(l1, mu, lam)
    P11 = mu * (l1 - 1 / l1) + lam * np.log(l1 * l2) / l1
    model, p = neo_hookean("lame"), jnp.array([E, nu])
    F = jnp.diag(jnp.array([l1, l2]))
    W, P, _ = model.point_terms(p)
    derived = model.derived_terms(p, model.volume_modulus(p))[1]
    for stress in (np.asarray(P(F)), np.asarray(derived(F))):
        assert stress[1, 1] == pytest.approx(0.0, abs=1e-14 * mu)
        assert stress[0, 0] == pytest.approx(P11, rel=1e-12)
        assert stress[0, 1] == stress[1, 0] == 0.0
    found = minimize_scalar(
        lambda b: float(W(jnp.diag(jnp.array([l1, b])))),
        bounds=(0.5 * l2, 1.5 * l2),
        method="bounded",
        options={"xatol": 1e-10},
    )
    assert found.x == pytest.approx(l2, rel=1e-7)
    if l1 > 1:  # the 3D-consistent form contracts less than the paper's (nu' 0.43 against 0.52)
        assert l2 > uniaxial_lateral_stretch(l1, mu, E / (3 * (1 - 2 * nu)))


@pytest.fixture(scope="module")
def block():
    """A 10 x 10 solid block (four solid cells, an affine map), displacement and mixed, both forms;
    its control points and the area."""
    spec = scene_from_config(BLOCK)
    discs = {
        (f, v): discretise(spec, Fidelity(5, 3), material=Material(f, law_of("neo_hookean"), v))
        for f in ("displacement", "mixed")
        for v in ("bulk", "lame")
    }
    X = discs["displacement", "bulk"].reference_points(discs["displacement", "bulk"].init_params())
    return discs, X, 100.0


@pytest.mark.parametrize("volumetric", ["bulk", "lame"])
def test_mixed_formulation_agrees_with_displacement_on_a_homogeneous_state(block, volumetric):
    """u = (F - I) X on an affine block is homogeneous: each element's mean dilatation is J, so the
    mixed energy and forces equal the displacement formulation's, and the energy is W(F) times the
    area with k the chosen coefficient: kappa (bulk) or lam (lame) in mu/2 (I1 - 2 - 2 log J)
    + k/2 (log J)^2 (closed form)."""
    discs, X, area = block
    nu, F = 0.3, np.array([[1.3, 0.2], [-0.1, 0.8]])
    p = jnp.array([E, nu])
    u = X @ jnp.asarray(F - np.eye(2)).T
    mu, logJ = E / (2 * (1 + nu)), np.log(np.linalg.det(F))
    k = E / (3 * (1 - 2 * nu)) if volumetric == "bulk" else lame_lambda(E, nu)
    W = mu / 2 * (np.sum(F * F) - 2 - 2 * logJ) + k / 2 * logJ**2
    out = {}
    for formulation in ("displacement", "mixed"):
        solid = discs[formulation, volumetric].solid
        quad = quadrature(solid, X)
        energy = float(strain_energy(solid, quad, u, p))
        assert energy == pytest.approx(W * area, rel=1e-12)
        out[formulation] = energy_force_tangents(solid, quad, u, p)
    assert float(out["mixed"][0]) == pytest.approx(float(out["displacement"][0]), rel=1e-12)
    scale = float(jnp.max(jnp.abs(out["displacement"][1])))
    np.testing.assert_allclose(out["mixed"][1], out["displacement"][1], atol=1e-12 * scale)


# -- which form a configuration gets -------------------------------------------------------------


@pytest.mark.parametrize(
    "scene, material, form",
    [
        ("translation", None, "bulk"),  # the paper's scenes state bulk
        ("rotation_double", "ogden", "bulk"),  # a law's own file leaves it to the scene
        ("digital_mnist", None, "bulk"),
        ("translation", "dragon_skin_10", "lame"),  # a shipped elastomer states lame
        (BLOCK, None, "lame"),  # a new scene: the default
        ({**BLOCK, "volumetric": "bulk"}, None, "bulk"),
        (BLOCK, {"volumetric": "bulk"}, "bulk"),  # stated on the material: it wins
        ("translation", {"volumetric": "lame"}, "lame"),
    ],
)
def test_volumetric_auto_takes_the_scenes_form_else_lame(scene, material, form):
    s = library_settings(scene, material=material)
    assert s.material.volumetric == form
    assert material_of(s.material).volumetric == form


ELASTOMERS = ("dragon_skin_10", "dragon_skin_30", "ecoflex_0030", "ecoflex_0050")


def test_shipped_elastomers_state_lame_and_law_files_leave_it_to_the_scene():
    for name in config.options("material"):
        stated = config.load("material", name).get("volumetric", "auto")
        assert stated == ("lame" if name in ELASTOMERS else "auto"), name
    for name in ("translation", "rotation_single", "rotation_double", "shape_matching"):
        assert config.load("scene", name)["volumetric"] == "bulk"


def test_a_law_without_a_volume_term_refuses_a_volumetric_form():
    with pytest.raises(ConfigError, match="material.volumetric has no effect: law st_venant"):
        MaterialConfig(law="st_venant_kirchhoff", volumetric="lame")
    s = library_settings(BLOCK, material="st_venant_kirchhoff")
    assert s.material.volumetric == "auto"
    record = plane_strain_record(material_of(s.material), jnp.array([E, 0.3]))
    assert record["volumetric"] is None
    assert record["poisson"] == pytest.approx(0.3 / 0.7, rel=1e-12)  # linear elasticity's


def test_a_lame_term_that_would_be_negative_is_refused_naming_nu():
    """Mooney-Rivlin's psi gives the Lame constant 4 C01 of its own: at nu = 0.1 and C01 = C10 / 4
    the lame coefficient 2 mu0 nu / (1 - 2 nu) - 4 C01 = 0.00675 - 0.0108 is negative, and the
    energy would fall without bound as J -> 0; nu must be at least 4 C01 / (2 (mu0 + 4 C01)) =
    0.0108 / 0.0756 = 0.1429.  A Neo-Hookean's lame coefficient is negative with nu (0 at nu = 0,
    where -mu log J still bounds the energy).  bulk keeps kappa > 0.  The config and the library
    (Material.check, before a solve) refuse alike."""
    material = {"law": "mooney_rivlin", "E": None, "nu": 0.1}
    material["parameters"] = {"C10": 0.0108, "C01": 0.0027}
    with pytest.raises(ConfigError, match=r"material.nu must be at least 0.1429 for lame"):
        library_settings(BLOCK, material={**material, "volumetric": "lame"})
    assert library_settings(BLOCK, material={**material, "volumetric": "bulk"}).material.nu == 0.1
    nh = Material(law=law_of("neo_hookean"), volumetric="lame")
    with pytest.raises(ValueError, match=r"negative Poisson's ratio .* nu must be at least 0 "):
        nh.check(np.array([E, -0.3]))
    nh.check(np.array([E, 0.0]))
    Material(law=law_of("neo_hookean"), volumetric="bulk").check(np.array([E, -0.3]))


def test_plane_strain_record_states_the_form_and_its_moduli():
    """nma.simulate's `plane_strain`: at nu = 0.3 the paper's form is 1.064 times E / (1 - nu^2)
    with 0.52 across, lame exactly E / (1 - nu^2) and 0.4286."""
    p = jnp.array([E, 0.3])
    bulk, lame = (plane_strain_record(neo_hookean(v), p) for v in ("bulk", "lame"))
    assert bulk["volumetric"] == "bulk" and lame["volumetric"] == "lame"
    assert bulk["modulus_3d_consistent"] == pytest.approx(E / 0.91, rel=1e-14)
    assert bulk["modulus"] / bulk["modulus_3d_consistent"] == pytest.approx(1.064, rel=1e-12)
    assert bulk["poisson"] == pytest.approx(0.52, rel=1e-12)
    assert lame["modulus"] == pytest.approx(lame["modulus_3d_consistent"], rel=1e-12)
    assert lame["poisson"] == pytest.approx(lame["poisson_3d_consistent"], rel=1e-12)


def test_checkpoints_from_before_the_setting_read_as_the_papers_form():
    """A checkpoint's record without material.volumetric means bulk (ABSENT_MEANS), the form such a
    record was solved with: a paper scene's run continues it, a lame run refuses it."""
    import json

    from conftest import compose_cfg
    from nma.train.checkpoint import check_fingerprint
    from nma.train.runs import absent_means, fingerprint, validate

    paper = validate(compose_cfg("task=translation", "logger=none"))
    lame = validate(compose_cfg("task=translation", "logger=none", "material.volumetric=lame"))
    assert paper.material.volumetric == "bulk" and lame.material.volumetric == "lame"
    before = fingerprint(paper)
    before["material"] = {k: v for k, v in before["material"].items() if k != "volumetric"}
    record = {"config": json.dumps(before)}
    check_fingerprint("c", record, fingerprint(paper), absent_means(paper))
    with pytest.raises(ConfigError, match="material.volumetric: 'bulk' -> 'lame'"):
        check_fingerprint("c", record, fingerprint(lame), absent_means(lame))


def test_a_saved_run_without_the_setting_is_re_read_in_the_papers_form(translation_run, tmp_path):
    """A run's .hydra/config.yaml without material.volumetric and scene.volumetric (a run saved
    with neither): nma.evaluate and nma.export (load_run) solve it with bulk, the form it trained
    with, not with the default a scene without a statement gets."""
    from omegaconf import OmegaConf

    from conftest import copy_run
    from nma.train.runs import load_run

    run = copy_run(translation_run, tmp_path / "run")
    saved = run / ".hydra" / "config.yaml"
    cfg = OmegaConf.to_container(OmegaConf.load(saved))
    cfg["material"].pop("volumetric", None)
    cfg["scene"].pop("volumetric", None)
    OmegaConf.save(OmegaConf.create(cfg), saved)
    assert load_run(run)[0].material.volumetric == "bulk"
