"""The narrowest ligament (nma.geometry.features): its closed form, shapely's measure, its gradient,
the trainer.min_feature setting and a training run that enforces it."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from conftest import FAST, compose_cfg, train_in_process
from nma import config
from nma.errors import ConfigError
from nma.geometry.features import Ligaments

CELL = 5.0  # conf/scene/translation.yaml: cell_size


@pytest.fixture(scope="module")
def translation():
    from nma.simulator import Simulator

    return Simulator.from_config(
        config.load("scene", "translation"), config.load("fidelity", "fast")
    )


def uniform(sim, r):
    g = sim.init_params()
    return {**g, "radii": jnp.full_like(g["radii"], r)}


@pytest.mark.parametrize("r", [0.5, 0.8])
def test_square_pores_have_the_closed_form_ligament(translation, r):
    """Equal radii r make every pore its cell scaled by r about the centre
    (nma.geometry.design.pore_nets): a square of side r L.  So the wall between two neighbouring
    pores is L (1 - r) and between a pore of an edge cell and the outer boundary L (1 - r) / 2, the
    narrowest.  Straight spans and sampled corners: the measure is exact, and says so (resolution
    0)."""
    X = translation.reference_points(uniform(translation, r))
    lig = Ligaments.of(translation.disc.mesh, X)
    rep = lig.report(X)
    assert rep["min_ligament"] == pytest.approx(CELL * (1 - r) / 2, abs=1e-12)
    assert (
        rep["min_ligament_between"][0] == "outer boundary"
        and rep["min_ligament_resolution"] < 1e-12
    )
    widths = np.asarray(lig.pair_widths(X))
    pores = np.all(lig.pairs > 0, axis=1)
    # pore to neighbouring pore
    assert np.min(widths[pores]) == pytest.approx(CELL * (1 - r), abs=1e-12)
    assert float(lig.width(X)) == rep["min_ligament"]


def test_it_is_shapelys_measure_within_its_stated_resolution(translation):
    """On the same polylines it is shapely's distance (nma.export.fabrication_report's measure) to
    rounding; against shapely on 64 points per knot span, the curves themselves to about 1e-5, it is
    within the resolution it states.  A random design: curved pore sides."""
    from nma.export import fabrication_report
    from nma.geometry.outline import Outline

    geom = translation.disc.design.random_params(np.random.default_rng(3))
    X = np.asarray(translation.reference_points(geom))
    lig = Ligaments.of(translation.disc.mesh, X)
    rep = lig.report(X)
    outline = Outline.of(translation.disc.mesh, X)
    assert rep["min_ligament"] == pytest.approx(
        fabrication_report(outline, lig.per_span)["min_ligament"], abs=1e-12
    )
    fine = fabrication_report(outline, 64)["min_ligament"]
    assert 0 < rep["min_ligament_resolution"] < 0.02
    assert abs(rep["min_ligament"] - fine) <= rep["min_ligament_resolution"]


def test_gradient_matches_central_differences(translation):
    """d(width)/d(radii) and d(penalty)/d(radii) by autodiff against central differences (step 1e-6)
    of the same functions, at a random design whose narrowest ligament is attained once."""
    geom = translation.disc.design.random_params(np.random.default_rng(1))
    X0 = translation.reference_points(geom)
    lig = Ligaments.of(
        translation.disc.mesh,
        X0,
        bound=1.2 * float(Ligaments.of(translation.disc.mesh, X0).width(X0)),
    )
    for fn in (lig.width, lig.penalty):
        f = jax.jit(lambda g: fn(translation.reference_points(g)))
        grad = np.asarray(
            jax.grad(lambda g: fn(translation.reference_points(g)))(geom)["radii"]
        ).ravel()
        assert np.count_nonzero(grad) >= 1
        for k in np.argsort(-np.abs(grad))[:3]:
            e = np.zeros(grad.size)
            e[k] = 1e-6
            e = jnp.asarray(e.reshape(geom["radii"].shape))
            fd = (
                f({**geom, "radii": geom["radii"] + e}) - f({**geom, "radii": geom["radii"] - e})
            ) / 2e-6
            assert grad[k] == pytest.approx(float(fd), rel=1e-5, abs=1e-7)


@pytest.mark.parametrize(
    "override, named",
    [
        ("trainer.min_feature=0", "trainer.min_feature"),
        ("trainer.feature_penalty=-1", "trainer.feature_penalty"),
    ],
)
def test_a_bad_value_names_the_setting_and_its_range(override, named):
    from nma.train.runs import validate

    with pytest.raises(ConfigError, match=named.replace(".", r"\.")) as err:
        validate(compose_cfg("task=translation", override, "part.scale=2"))
    assert ("(0, 10000]" if "min_feature" in named else "[0, inf)") in str(err.value)


def test_min_feature_without_the_parts_scale_is_refused():
    """A size in mm means nothing where the scene's units are not physical (part.scale null)."""
    from nma.train.runs import validate

    with pytest.raises(ConfigError, match=r"trainer\.min_feature=0\.8 \(mm\) needs part\.scale"):
        validate(compose_cfg("task=translation", "trainer.min_feature=0.8"))


def test_the_default_run_neither_bounds_nor_records_a_bound():
    from nma.train.runs import fingerprint, validate

    s = validate(compose_cfg("task=translation"))
    assert s.trainer.min_feature is None and "min_feature" not in fingerprint(s)["trainer"]
    bounded = validate(compose_cfg("task=translation", "trainer.min_feature=0.8", "part.scale=2"))
    assert (
        fingerprint(bounded)["trainer"]["min_feature"] == 0.8
        and fingerprint(bounded)["trainer"]["part_scale"] == 2
    )


def test_training_widens_ligaments_below_the_bound_and_reports_the_width(tmp_path, caplog):
    """Two steps of translation with a 3 mm bound at 2 mm per unit (1.5 units) on the initial
    design, whose narrowest ligament is 1.25 units (radii 0.5: the closed form above): the penalty
    widens it, the log says the bound is not met yet, and metrics.json records the width in units
    and in mm, and the ligaments still below the bound."""
    with caplog.at_level("WARNING", logger="nma.train.trainer"):
        train_in_process(
            tmp_path,
            "task=translation",
            "logger=none",
            *FAST,
            "trainer.min_feature=3",
            "part.scale=2",
        )
    assert "ligaments below trainer.min_feature = 3 mm" in caplog.text
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["min_ligament"] > 1.25 and m["min_ligament_mm"] == pytest.approx(2 * m["min_ligament"])
    # in mm
    assert m["min_feature"] == 3 and all(w < 3 for _, _, w in m["ligaments_below_min_feature"])
