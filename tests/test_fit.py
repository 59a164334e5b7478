"""Fitting a law to test data (nma.fit): synthetic data made from known parameters is fitted back to
them, the Soft Robotics Materials Database's file format reads as it is, the command writes a
material file."""

import json
import re
import subprocess
import sys
import warnings

import jax.numpy as jnp
import numpy as np
import pytest
import yaml

from nma.errors import ConfigError
from nma.fit import fit, read
from nma.mechanics.laws import law_of, nominal_stress
from nma.schema import MaterialConfig
from nma.schema.commands import FitConfig


def synthetic(path, law, p, modes=("uniaxial", "biaxial", "planar"), top=2.0):
    """A CSV of the law's own nominal stresses (nma.mechanics.laws.nominal_stress, checked against
    Treloar's closed forms in test_laws.py) in each mode, at 25 stretches each from 1.04 to
    `top`."""
    lam = np.linspace(1.04, top, 25)
    lines = ["mode,strain,stress"]
    for mode in modes:
        for x, s in zip(lam, np.asarray(nominal_stress(law, jnp.asarray(p), mode, lam))):
            lines.append(f"{mode},{float(x) - 1.0!r},{float(s)!r}")
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize(
    "law, names, p, rtol",
    [
        ("yeoh", (), [0.1, -0.004, 0.0006], 1e-7),
        ("ogden", ("mu1", "alpha1", "mu2", "alpha2"), [0.2, 1.8, -0.01, -2.5], 1e-5),
        ("arruda_boyce", (), [0.2, 2.5], 1e-7),  # from its declared defaults' start (Law.fit_start)
    ],
)
def test_data_made_from_known_parameters_is_fitted_back_to_them(tmp_path, law, names, p, rtol):
    """Three modes determine the law: the fit finds the parameters that made the data (Ogden's up to
    the order of its terms) and its errors are round-off."""
    data = synthetic(tmp_path / "d.csv", law_of(law, names), p)
    out = fit(FitConfig(data=str(data), law=law, terms=len(names) // 2 or 2, starts=4))["material"]
    got = list(out["parameters"].values())
    if law == "ogden" and got[1] < 0:  # the same law with its terms in the other order
        got = got[2:] + got[:2]
    np.testing.assert_allclose(got, p, rtol=rtol)
    assert out["fit"]["rms_relative_error"] < 1e-6 and out["fit"]["modes"] == [
        "biaxial",
        "planar",
        "uniaxial",
    ]
    assert out["stretches"] == [
        round(2.0**-0.5, 4),
        2.0,
    ]  # the data's: uniaxial to 2.0 squeezes the sides


def test_the_soft_robotics_databases_format_reads_as_it_is(tmp_path):
    """Metadata rows first, then a semicolon-separated header (the database's layout: see its
    Tensile-Tests-Data/*.csv); rows past max_strain are left out."""
    rows = [
        "PARAMETER;INFO;URL;;",
        "Specimen Thickness (mm);3;;;",
        "Material;Test;;;",
        ";;;;",
        "Time (s);True Strain;True Stress (MPa);Engineering Strain;Engineering Stress (MPa)",
    ]
    rows += [f"{t};0;0;{e};{2 * e}" for t, e in enumerate([0.1, 0.2, 0.4, 0.8, 1.6])]
    (tmp_path / "t.csv").write_text("\n".join(rows) + "\n")
    modes, stretches, stresses = read(
        tmp_path / "t.csv", "Engineering Strain", "Engineering Stress (MPa)", "uniaxial", 1.0
    )
    assert modes.tolist() == ["uniaxial"] * 4
    np.testing.assert_allclose(stretches, [1.1, 1.2, 1.4, 1.8])
    np.testing.assert_allclose(stresses, [0.2, 0.4, 0.8, 1.6])


def test_the_command_writes_a_material_file(tmp_path):
    """`python -m nma.fit`: exit 0, one JSON line, and a YAML file that is a checked material."""
    data = synthetic(tmp_path / "d.csv", law_of("mooney_rivlin"), [0.3, 0.05], modes=("uniaxial",))
    out = tmp_path / "mat.yaml"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "nma.fit",
            f"data={data}",
            "law=mooney_rivlin",
            "name=test rubber",
            f"output={out}",
            f"hydra.run.dir={tmp_path / 'run'}",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    written = yaml.safe_load(out.read_text())
    assert written == result["material"] and out.read_text().startswith(
        "# test rubber: a mooney_rivlin law"
    )
    cfg = MaterialConfig(**written)
    np.testing.assert_allclose(list(cfg.parameters.values()), [0.3, 0.05], rtol=1e-7)
    assert cfg.unit == "MPa" and cfg.nu == 0.499 and cfg.fit["sha256"] and cfg.fit["points"] == 25


@pytest.mark.parametrize(
    "overrides, message",
    [
        (
            {"stress_column": "force"},
            "no row names both columns strain_column='strain' and stress_column='force'",
        ),
        (
            {"max_strain": 0.01},
            "0 rows with numbers in both columns up to max_strain=0.01; a fit needs at least 3",
        ),
        (
            {"law": "neo_hookean"},
            "law must be one of ['arruda_boyce', 'gent', 'mooney_rivlin', 'ogden', 'yeoh']",
        ),
        ({"data": "/nonexistent.csv"}, "data must name a CSV file"),
        ({"terms": 4}, "terms must be an integer in [1, 3]"),
        ({"data": "negative"}, "25 of 25 rows have a stress of the other sign than their strain"),
    ],
)
def test_bad_input_names_the_field(tmp_path, overrides, message):
    data = synthetic(tmp_path / "d.csv", law_of("mooney_rivlin"), [0.3, 0.05], modes=("uniaxial",))
    if overrides.get("data") == "negative":  # the stress column of the other sign
        rows = data.read_text().splitlines()
        data.write_text(
            "\n".join(
                rows[:1] + [r.rsplit(",", 1)[0] + ",-" + r.rsplit(",", 1)[1] for r in rows[1:]]
            )
        )
        overrides = {}
    with pytest.raises(ConfigError) as err:
        fit(FitConfig(**{"data": str(data), **overrides}))
    assert message in str(err.value)


def test_a_law_that_cannot_follow_the_data_stably_is_refused(tmp_path):
    """Data that soften (a curve no stable Mooney-Rivlin follows: a Mooney-Rivlin softens only where
    it is unstable) are refused with the reason, not written."""
    lam = np.linspace(1.05, 3.0, 30)
    (tmp_path / "s.csv").write_text(
        "strain,stress\n" + "\n".join(f"{x - 1},{np.log(x)}" for x in lam) + "\n"
    )
    with pytest.raises(ConfigError, match="law=mooney_rivlin: no fit from 3 starts is stable"):
        fit(FitConfig(data=str(tmp_path / "s.csv"), law="mooney_rivlin", starts=3))


def test_a_database_file_reads_past_metadata_commas_and_a_zero_offset(tmp_path):
    """The database's layout with a comma in a metadata row (its `Lab` row), a first row whose
    stress is the test's offset about zero (of the other sign, within 5% of the largest stress: left
    out), and the same with decimal commas."""
    rows = [
        "PARAMETER;INFO;;;",
        "Lab;Univ. Savoie Mont Blanc - SYMME Lab, 7400 Annecy, France;;;",
        ";;;;",
        "Time (s);True Strain;True Stress (MPa);Engineering Strain;Engineering Stress (MPa)",
        "0.1;0;0;0.04;-0.0007",
    ]
    rows += [f"{t};0;0;{e};{2 * e}" for t, e in enumerate([0.1, 0.2, 0.4, 0.8])]
    text = "\n".join(rows) + "\n"
    for name, content in (("dot.csv", text), ("comma.csv", text.replace(".", ","))):
        (tmp_path / name).write_text(content)
        modes, stretches, stresses = read(
            tmp_path / name, "Engineering Strain", "Engineering Stress (MPa)", "uniaxial", None
        )
        np.testing.assert_allclose(stretches, [1.1, 1.2, 1.4, 1.8])
        np.testing.assert_allclose(stresses, [0.2, 0.4, 0.8, 1.6])


@pytest.mark.parametrize(
    "rows, says",
    [
        ([(0.1, 0.2), (0.2, 0.2), (0.3, 0.2), (0.4, 0.2)], "the stress is 0.2 at every strain"),
        ([(0.1, 0.0), (0.2, 0.0), (0.3, 0.0)], "the stress is 0 at every strain"),
        (
            [(0.5, 0.1), (0.5, 0.2), (0.5, 0.3), (0.5, 0.4)],
            "4 rows at 1 distinct strain; a fit needs the stress at at least 3",
        ),
        (
            [(0.1, 0.1), (0.2, float("nan")), (0.3, 0.3), (0.4, 0.4)],
            "row 3 has stress 'nan': every number must be finite",
        ),
        (
            [(0.1, 0.1), (-1.2, -0.5), (0.3, 0.3), (0.4, 0.4)],
            "row 3 has strain -1.2: an engineering strain must exceed -1",
        ),
        (
            [(0.1, 0.4), (0.2, 0.3), (0.3, 0.2), (0.4, 0.1)],
            "in the uniaxial test the stress does not grow with the strain",
        ),
        ([(0.1, 0.1), (0.2, 0.2)], "2 rows with numbers in both columns; a fit needs at least 3"),
    ],
)
def test_degenerate_data_are_refused_naming_the_problem(tmp_path, rows, says):
    """One line saying what is wrong with the data, before any fit, and no numpy warning."""
    lines = "\n".join(f"{e},{s}" for e, s in rows)
    (tmp_path / "d.csv").write_text(f"strain,stress\n{lines}\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ConfigError) as err:
            fit(FitConfig(data=str(tmp_path / "d.csv"), law="mooney_rivlin", starts=1))
    assert says in str(err.value) and "\n" not in str(err.value)


def test_a_law_needs_as_many_points_as_parameters(tmp_path):
    data = synthetic(tmp_path / "d.csv", law_of("mooney_rivlin"), [0.3, 0.05], modes=("uniaxial",))
    data.write_text("\n".join(data.read_text().splitlines()[:5]) + "\n")
    says = "4 distinct points; law=ogden terms=3 has 6 parameters"
    with pytest.raises(ConfigError, match=re.escape(says)):
        fit(FitConfig(data=str(data), law="ogden", terms=3, starts=1))


@pytest.mark.parametrize("p, at_bound", [([0.2, 10.0], False), ([0.2, 1e9], True)])
def test_gents_jm_is_bounded_where_it_is_neo_hookeans(tmp_path, p, at_bound):
    """Stiffening data give Gent's Jm back; Neo-Hookean data (Jm 1e9) stop Jm at its bound, 1000
    times the data's largest I1 - 3, where Gent is Neo-Hookean's within 0.1% over the data: the
    record says so and names the Neo-Hookean material, and the stresses still follow the data."""
    data = synthetic(tmp_path / "d.csv", law_of("gent"), p, modes=("uniaxial",))
    out = fit(FitConfig(data=str(data), law="gent", starts=2))["material"]
    jm, bound = out["parameters"]["Jm"], 1e3 * (2.0**2 + 2.0 / 2.0 - 3.0)
    if at_bound:
        note = out["fit"]["note"]
        assert jm == pytest.approx(bound, rel=1e-2) and "Jm is at its bound 2000" in note
        assert "material.law=neo_hookean with E = 2 mu (1 + nu)" in note
        assert out["fit"]["max_relative_error"] < 2e-3
    else:
        np.testing.assert_allclose([out["parameters"]["mu"], jm], p, rtol=1e-6)
        assert "note" not in out["fit"]
