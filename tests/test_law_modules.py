"""Each hyperelastic law one module of nma/mechanics/laws/, declared once: the registry, the laws'
material files and the settings' checks come from the declaration; plane strain is one reduction of
the 3D energy; Neo-Hookean's own energy gives its closed forms; and parameters that are not the
law's are refused naming the law, the parameter and its range."""

import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nma import config
from nma.errors import ConfigError
from nma.mechanics.laws import LAWS, drucker_unstable, law_names, law_of, nominal_stress
from nma.mechanics.material import Material, from_lame
from nma.mechanics.material import material as mat_of
from nma.resolve import material_params
from nma.schema import MaterialConfig

NU = 0.3
ROOT = Path(__file__).resolve().parent.parent
LAWS_DIR = ROOT / "nma" / "mechanics" / "laws"


def test_every_law_module_registers_one_law_declared_with_defaults_in_range():
    """nma/mechanics/laws/<name>.py registers the law <name> on import (base and homogeneous are not
    laws); its parameters' names are unique, and each default lies in its declared range."""
    modules = sorted(
        p.stem for p in LAWS_DIR.glob("*.py") if p.stem not in ("__init__", "base", "homogeneous")
    )
    assert list(law_names()) == modules and "arruda_boyce" in modules
    for name in modules:
        law = law_of(name)
        assert type(law).__module__ == f"nma.mechanics.laws.{name}" and LAWS.get(name) is type(law)
        declared = [p.name for p in type(law).parameters]
        assert len(set(declared)) == len(declared), name
        assert all(p.admits(p.default) for p in type(law).parameters if p.default is not None), name
        assert law.shear_modulus({**law.defaults(), "nu": 0.3}) > 0, name
    with pytest.raises(ValueError, match="material.law 'gent' is registered twice"):
        LAWS.register("gent")(type(law_of("gent")))


def test_each_laws_material_file_is_its_declaration():
    """conf/material/<law>.yaml is what experiments/settings_reference.py writes from the law's
    declaration (`make settings-reference`), and loads as that law with its declared defaults."""
    sys.path.insert(0, str(ROOT / "experiments"))
    try:
        import settings_reference
    finally:
        sys.path.pop(0)
    for path, text in settings_reference.material_files().items():
        assert text is not None and path.read_text() == text, (
            f"{path.name} is stale: python experiments/settings_reference.py"
        )
    for name in law_names():
        cfg = MaterialConfig(**config.load("material", name))
        assert cfg.law == name and cfg.values == law_of(name).defaults()


@pytest.mark.parametrize("law", sorted(law_names()))
def test_every_laws_plane_strain_is_its_3d_energy_at_unit_third_stretch(law):
    """psi_plane(C) of the 2 x 2 C = diag(a^2, b^2) is the law's psi of the principal stretches
    (a, b, 1), and its reference is free of stress: P(I) = 0 with its default parameters."""
    model = Material(law=law_of(law))
    p = material_params(MaterialConfig.of_law(law))
    q, (a, b) = model.named(p), (1.3, 0.8)
    np.testing.assert_allclose(
        model.law.psi_plane(q, jnp.diag(jnp.array([a * a, b * b]))),
        model.law.psi_principal(q, a, b, 1.0),
        rtol=1e-13,
    )
    mu0 = float(model.moduli(p)[0])
    np.testing.assert_allclose(model.point_terms(p)[1](jnp.eye(2)), 0.0, atol=1e-14 * mu0)


def test_neo_hookeans_own_energy_gives_its_closed_forms():
    """Neo-Hookean's psi = mu/2 (I1 - 3) in the compressible form, differentiated by JAX, is the
    closed-form W, P and dP/dF the model solves with (material.py), at random F, to round-off."""
    model, p = Material(), jnp.array([0.07, NU])
    mu, kappa = model.moduli(p)
    assert model.law.closed_form and float(mu) == 0.07 / (2 * (1 + NU))
    assert float(model.nu(p)) == NU and dict(model.named(p)) == {"E": 0.07, "nu": NU}
    rng = np.random.default_rng(3)
    Fs = jnp.asarray(np.eye(2) + 0.3 * rng.standard_normal((20, 2, 2)))
    Fs = Fs[np.asarray(jax.vmap(jnp.linalg.det)(Fs)) > 0.2]
    for closed, derived in zip(model.point_terms(p), model.derived_terms(p, kappa)):
        np.testing.assert_allclose(derived(Fs), closed(Fs), rtol=1e-12, atol=1e-15)


def test_incompressible_neo_hookean_has_shear_modulus_e_over_three():
    """nominal_stress in uniaxial tension at nu = 0.5: (E / 3) (l - l^-2) (Treloar)."""
    E, lam = 0.09, np.linspace(0.6, 2.5, 7)
    np.testing.assert_allclose(
        nominal_stress(law_of("neo_hookean"), [E], "uniaxial", lam),
        E / 3 * (lam - lam**-2),
        rtol=1e-13,
    )


# -- parameters that are not the law's ---------------------------------------------------------


@pytest.mark.parametrize(
    "law, values, says",
    [
        (
            "yeoh",
            {"C10": 0.1, "C20": -0.05, "C30": 0.0},
            "not stable (Drucker) for principal stretches in "
            "material.stretches=[0.5, 2.0]: uniaxial tension at stretch 0.5",
        ),
        ("gent", {"mu": 0.1, "Jm": 5.0}, "beyond the law's limit"),
        (
            "mooney_rivlin",
            {"C10": 0.1, "C01": -0.2},
            "initial shear modulus -0.2: it must be positive",
        ),
        (
            "ogden",
            {"mu1": 0.1, "alpha1": 0.0},
            "material.parameters.alpha1 must be a finite number in [-100, -0.01] or [0.01, 100], "
            "got 0.0",
        ),
        ("ogden", {"mu1": 0.1}, "material.parameters.alpha1 is missing"),
        ("yeoh", {"C10": 0.1, "C20": 0.0, "C30": 0.0, "C40": 1.0}, "['C40'] are not law yeoh's"),
    ],
)
def test_unstable_or_malformed_parameters_are_refused_naming_the_range(law, values, says):
    with pytest.raises(ConfigError, match=None) as err:
        MaterialConfig(law=law, E=None, parameters=values)
    assert says in str(err.value)


def test_a_law_takes_its_own_parameters_not_neo_hookeans():
    with pytest.raises(
        ConfigError,
        match=r"material.E is not a parameter of law gent, which takes "
        r"material.parameters \['mu', 'Jm'\]",
    ):
        MaterialConfig(law="gent", parameters={"mu": 0.1, "Jm": 50.0})
    with pytest.raises(
        ConfigError, match=r"material.parameters \['mu'\] are not law neo_hookean's"
    ):
        MaterialConfig(parameters={"mu": 0.1})
    with pytest.raises(ConfigError, match="material.E is given twice"):
        MaterialConfig(parameters={"E": 0.1})


def test_a_law_without_parameters_takes_its_declared_defaults():
    """material.law=<law> material.E=null: the law's declared defaults, as its file holds them."""
    cfg = MaterialConfig(law="arruda_boyce", E=None)
    assert cfg.values == {"mu": 0.02659, "lambda_m": 7.0} == law_of("arruda_boyce").defaults()
    assert MaterialConfig(law="neo_hookean", E=None).values == {"E": 0.07}
    assert list(MaterialConfig(law="ogden", E=None).values) == ["mu1", "alpha1", "mu2", "alpha2"]


@pytest.mark.parametrize(
    "law, p, says",
    [
        ("gent", [0.1], "p must hold 2 parameters, got 1: law gent takes [mu, Jm]"),
        ("gent", [0.1, 5.0, 3.0], "p must hold 2 parameters, got 3: law gent takes [mu, Jm]"),
        ("yeoh", [0.1], "p must hold 3 parameters, got 1: law yeoh takes [C10, C20, C30]"),
        (
            "mooney_rivlin",
            [[0.1, 0.0]],
            "p must have shape (n,), got (1, 2); law mooney_rivlin takes",
        ),
        ("gent", [np.nan, 5.0], "p must be finite, got [nan, 5.0]; law gent takes [mu, Jm]"),
        ("gent", [0.1, -5.0], "p = [mu, Jm] must have Jm in (0, 1e12] (law gent), got -5"),
        (
            "ogden",
            [0.1, 0.0],
            "p = [mu1, alpha1] must have alpha1 in [-100, -0.01] or [0.01, 100] (law ogden), got 0",
        ),
    ],
)
def test_a_laws_stress_refuses_parameters_not_the_laws(law, p, says):
    """Too few, too many, not finite or out of range: refused naming the law and what it takes,
    not a plausible number from the parameters that are there."""
    names = ("mu1", "alpha1") if law == "ogden" else ()
    with pytest.raises(ConfigError) as err:
        nominal_stress(law_of(law, names), jnp.asarray(p), "uniaxial", 1.5)
    assert f"nominal_stress: {says}" in str(err.value)


def test_the_laws_functions_check_their_other_arguments_naming_them():
    gent, p = law_of("gent"), jnp.array([0.1, 5.0])
    cases = [
        (
            lambda: nominal_stress(gent, p, "shear", 1.5),
            ConfigError,
            "nominal_stress: mode must be one of",
        ),
        (
            lambda: nominal_stress(gent, p, "uniaxial", -1.5),
            ConfigError,
            "nominal_stress: lam must hold positive",
        ),
        (
            lambda: nominal_stress("gent", p, "uniaxial", 1.5),
            TypeError,
            "nominal_stress: law must be a Law",
        ),
        (lambda: law_of("hookean"), ConfigError, "material.law must be one of ['arruda_boyce', "),
        (
            lambda: drucker_unstable(law_of("yeoh"), jnp.array([0.1])),
            ConfigError,
            "drucker_unstable: p must hold 3 parameters, got 1: law yeoh takes [C10, C20, C30]",
        ),
        (
            lambda: drucker_unstable(gent, p, (2.0, 0.5)),
            ConfigError,
            "drucker_unstable: stretches must be (low, high) with 0 < low < high",
        ),
        (
            lambda: Material(law=gent).check(jnp.array([0.1, 5.0])),
            ValueError,
            "equilibrium: mat must be law gent's [mu, Jm, nu]: 3 numbers, got 2",
        ),
        (lambda: from_lame(-1.0, 2.0), ValueError, "from_lame: mu must be a finite number"),
        (lambda: mat_of("stiff", 0.3), TypeError, "material: E must be a real number"),
    ]
    for call, kind, says in cases:
        with pytest.raises(kind) as err:
            call()
        assert says in str(err.value)


OUTSIDE_LAW = '''"""A law written outside nma: Neo-Hookean with a quadratic term in I1 - 3."""
from nma.mechanics.laws import InvariantLaw, Parameter, register


@register
class Quadratic(InvariantLaw):
    name = "outside_quadratic"
    parameters = (
        Parameter("C10", 0.01346, "(0, inf)", "the coefficient of I1 - 3"),
        Parameter("C20", 0.001, "[0, inf)", "the coefficient of (I1 - 3)^2"),
    )

    def shear_modulus(self, q):
        return 2.0 * q["C10"]

    def stress_free(self, q):
        return 2.0 * q["C10"]

    def psi(self, q, I1, I2):
        return q["C10"] * (I1 - 3.0) + q["C20"] * (I1 - 3.0) ** 2
'''


def test_a_law_installed_from_outside_runs_by_its_name_alone(tmp_path):
    """An installed package's `nma.laws` entry point whose module is one law file: with no
    material file, `material=<its name>` composes it at its declared defaults and a scene solves
    in it (the static translation at 5 x 2, nma.simulate's JSON line)."""
    (tmp_path / "outside_law.py").write_text(OUTSIDE_LAW)
    dist = tmp_path / "outside_law-0.1.dist-info"  # what pip install leaves: found on sys.path
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: outside-law\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[nma.laws]\nquadratic = outside_law\n")
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    args = [
        "material=outside_quadratic",
        "scene=translation",
        "fidelity.quad_points=2",
        "actuation=[1.0,0.5]",
        f"hydra.run.dir={tmp_path / 'run'}",
    ]
    proc = subprocess.run(
        [sys.executable, "-m", "nma.simulate", *args],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["converged"] and out["valid"]
    assert out["material"] == {
        "law": "outside_quadratic",
        "C10": 0.01346,
        "C20": 0.001,
        "nu": 0.3,
        "formulation": "displacement",
        "volumetric": "bulk",  # the translation scene's, the paper's form
    }
