"""Settings that cannot do what they say (nma.schema.effect): a setting given where the rest of the
config leaves it unused is refused before any work, naming what would make it matter; a default
never is; a trainer.min_feature no design of the scene can meet is refused, saying what the scene
allows."""

import math
import re
from dataclasses import replace
from types import SimpleNamespace

import pytest
import yaml
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from conftest import compose_cfg
from nma import config, export
from nma.errors import ConfigError
from nma.run import validate_in
from nma.schema import SimulateConfig, build, register, scene_config
from nma.schema.commands import ExportConfig, FitConfig
from nma.schema.effect import check_export, check_min_feature, ligament_bound


def checked(tmp_path, *overrides):
    """nma.run's checked settings of these overrides (what its preflight runs before any work)."""
    return validate_in(compose_cfg(*overrides), tmp_path / "run")[0]


def assert_taken(s, overrides):
    """Each `a.b=value` override holds its value in the checked settings `s`."""
    for o in overrides:
        key, _, value = o.partition("=")
        if "." not in key:
            continue  # a config group's choice
        node = s
        for part in key.split("."):
            node = node[part] if isinstance(node, dict) else getattr(node, part)
        want = yaml.safe_load(value)
        assert node == want, (o, node)


def refused(message: str):
    """pytest.raises for a ConfigError whose one line begins with `message`."""
    return pytest.raises(ConfigError, match="^" + re.escape(message) + "[^\n]*$")


@pytest.mark.parametrize(
    "overrides, message",
    [
        (
            ["contact=off", "contact.stiffness=5"],
            "contact.stiffness=5.0 has no effect: contact is off; contact=on turns it on",
        ),
        (
            ["contact.distance=0.05"],
            "contact.distance=0.05 has no effect: contact is off",
        ),  # auto: off
        (
            ["dynamics.dt=0.1"],
            "dynamics.dt=0.1 has no effect: task translation is static, and dynamics is off",
        ),
        (["dynamics.steps=10"], "dynamics.steps=10 has no effect: task translation is static"),
        (
            ["part.thickness=10"],
            "part.thickness=10.0 has no effect: forces stay per unit thickness without part.scale",
        ),
        (
            ["trainer.feature_penalty=3"],
            "trainer.feature_penalty=3.0 has no effect: it weighs the "
            "trainer.min_feature bound: give trainer.min_feature (mm) too",
        ),
        (
            ["trainer.inversion_penalty=0", "trainer.inversion_margin=0.3"],
            "trainer.inversion_margin=0.3 has no effect: it is where the inversion penalty acts",
        ),
        (
            ["trainer.fields=none", "trainer.fields_samples=4"],
            "trainer.fields_samples=4 has no effect: trainer.fields=none writes no fields",
        ),
        (
            ["optim.final_fraction=0.3"],
            "optim.final_fraction=0.3 has no effect: it is the cosine schedule's last rate",
        ),
        (
            ["logger=none", "logger.project=mine"],
            "logger.project=mine has no effect: logger=none logs nothing",
        ),
    ],
)
def test_a_static_runs_setting_that_cannot_take_effect_is_refused(tmp_path, overrides, message):
    with refused(message):
        checked(tmp_path, "task=translation", *overrides)


@pytest.mark.parametrize(
    "overrides, message",
    [
        (
            ["dynamics=newmark", "dynamics.rho_inf=0.5"],
            "dynamics.rho_inf=0.5 has no effect: it is generalised_alpha's spectral radius",
        ),
        (
            ["dynamics=newmark", "dynamics.damping_frequency=2"],
            "dynamics.damping_frequency=2.0 has no effect: it is where dynamics.damping_ratio "
            "holds",
        ),
        (
            ["dynamics=newmark", "dynamics.ramp=3"],
            "dynamics.ramp=3.0 has no effect: it is nma.simulate's rise time",
        ),
    ],
)
def test_a_dynamics_setting_its_scheme_or_command_does_not_use_is_refused(
    tmp_path, overrides, message
):
    with refused(message):
        checked(tmp_path, "task=follow_path", "scene=translation", *overrides)


def test_an_evaluation_grid_for_named_cases_is_refused(tmp_path):
    with refused("task.eval_points=3 has no effect: it spaces the evaluation over a box"):
        checked(tmp_path, "task=strip_pore", "scene=strip", "task.eval_points=3")


@pytest.mark.parametrize(
    "overrides",
    [
        ["task=translation", "contact=on", "contact.stiffness=5", "contact.distance=0.05"],
        ["task=rotation_single", "contact.stiffness=5"],  # contact=auto: its scene's pores close
        ["task=translation", "material.nu=0.499", "contact.stiffness=5"],  # auto: on at nu 0.499
        [
            "task=follow_path",
            "scene=translation",
            "dynamics=generalised_alpha",
            "dynamics.rho_inf=0.5",
            "dynamics.dt=0.1",
            "dynamics.damping_ratio=0.1",
            "dynamics.damping_frequency=2",
        ],
        [
            "task=translation",
            "part.scale=2",
            "part.thickness=10",
            "trainer.min_feature=1",
            "trainer.feature_penalty=3",
        ],
        [
            "task=translation",
            "trainer.inversion_penalty=0.5",
            "trainer.inversion_margin=0.3",
            "trainer.fields=all",
            "trainer.fields_samples=4",
            "optim.schedule=cosine",
            "optim.final_fraction=0.3",
            "logger.project=mine",
        ],
        ["task=strip_spread", "scene=strip", "task.eval_points=3"],
    ],
)
def test_the_same_settings_where_they_take_effect_are_accepted(tmp_path, overrides):
    assert_taken(checked(tmp_path, *overrides), overrides)


@pytest.mark.parametrize(
    "overrides",
    [[f"experiment={e}"] for e in config.options("experiment")]
    + [
        ["debug=default", "task=translation"],
        ["debug=default", "task=follow_path", "scene=translation", "dynamics=newmark"],
    ],
)
def test_no_shipped_config_is_refused(tmp_path, overrides):
    """Every reproduction and the debug run as shipped: a config file's value is a default."""
    if overrides == ["experiment=repro_mnist_fit"]:  # a phase's input
        overrides = [*overrides, "task.lookup_run=outputs/repro/digital_mnist/lookup"]
    assert_taken(checked(tmp_path, *overrides), overrides)


def simulate_settings(*overrides) -> SimulateConfig:
    register()
    with initialize_config_dir(config_dir=str(config.CONF_DIR), version_base="1.3"):
        return build(SimulateConfig, compose(config_name="simulate", overrides=list(overrides)))


def test_nma_simulate_refuses_what_it_would_not_use_and_takes_its_rise_time():
    with refused(
        "dynamics.dt=0.5 has no effect: dynamics is off (dynamics.scheme=off): choose "
        "dynamics=newmark or dynamics=generalised_alpha"
    ):
        simulate_settings("scene=translation", "dynamics.dt=0.5")
    with refused(
        "contact.per_span=5 has no effect: contact is off (contact=auto, and scene "
        "translation leaves it off); contact=on turns it on"
    ):
        simulate_settings("scene=translation", "contact.per_span=5")
    assert (
        simulate_settings("scene=translation", "dynamics=newmark", "dynamics.ramp=3").dynamics.ramp
        == 3.0
    )


def test_nma_export_and_nma_fit_refuse_what_their_other_settings_leave_unused(tmp_path):
    """nma.export checks what the user gave (export.validate), not the settings it fills in."""
    with refused("thickness=5.0 has no effect: it is the STL's extrusion height"):
        check_export(ExportConfig(run="r", format="svg", thickness=5.0))
    with refused("load_fraction=0.3 has no effect: it sizes the load cases"):
        check_export(ExportConfig(run="r", load_fraction=0.3))
    check_export(ExportConfig(run="r", format="stl", thickness=5.0))
    check_export(
        ExportConfig(run="r", format="dxf", thickness=5.0, load_cases=True, load_fraction=0.3)
    )
    with refused("thickness=5.0 has no effect"):  # the command line's check, before the run is read
        export.validate(OmegaConf.create({"run": str(tmp_path), "format": "svg", "thickness": 5.0}))
    filled = replace(ExportConfig(run="r", format="svg"), scale=1.0, thickness=10.0)  # as export()
    assert filled.thickness == 10.0
    data = tmp_path / "d.csv"
    data.write_text("strain,stress\n0.1,0.01\n")
    with refused("terms=3 has no effect: it is Ogden's number of terms, and law yeoh"):
        FitConfig(data=str(data), law="yeoh", terms=3)
    assert FitConfig(data=str(data), law="ogden", terms=3).terms == 3


def test_the_ligament_bound_is_the_closed_form_wall_at_the_smallest_radius():
    """Translation's cells are 5 units and its radii at least 0.1: a pore of an edge cell is at
    most 0.9 x 2.5 from the outer boundary, which the design with every radius 0.1 attains
    (tests/test_features.py: the square pores' closed form); corner moves widen it by at most
    2 sqrt(2) corner_box; pores walled in by solid cells but for each other bound it through each
    other; a pore walled in all round gives no bound."""
    translation = scene_config(config.load("scene", "translation"))
    assert ligament_bound(translation) == (
        pytest.approx(0.9 * 2.5),
        "a pore's wall to the outer boundary",
    )
    moved = scene_config({**config.load("scene", "translation"), "corner_box": 1.0})
    assert ligament_bound(moved)[0] == pytest.approx(0.9 * 2.5 + 2 * math.sqrt(2))
    walled = scene_config(
        {
            "name": "w",
            "cells": "SSSS\nSPPS\nSSSS",
            "pinned": [[0, 0], [20, 0]],
            "radii_bounds": [0.2, 0.8],
        }
    )
    assert ligament_bound(walled) == (
        pytest.approx(0.8 * 5.0),
        "the wall between two neighbouring pores",
    )
    alone = scene_config({"name": "a", "cells": "SSS\nSPS\nSSS", "pinned": [[0, 0], [15, 0]]})
    assert ligament_bound(alone) is None  # nothing known, nothing refused


def test_a_min_feature_no_design_can_meet_is_refused_saying_what_the_scene_allows(tmp_path):
    base = ["task=translation", "part.scale=2"]
    checked(tmp_path, *base, "trainer.min_feature=4.5")  # the widest wall, 2.25 units, at 2 mm
    with refused(
        "trainer.min_feature=4.6 mm cannot be met by any design of scene translation: "
        "its narrowest ligament is at most 4.5 mm (2.25 units at part.scale=2: a pore's "
        "wall to the outer boundary at the smallest radius scene.radii_bounds[0]=0.1); "
        "lower trainer.min_feature, or raise part.scale"
    ):
        checked(tmp_path, *base, "trainer.min_feature=4.6")
    checked(tmp_path, "task=translation", "part.scale=3", "trainer.min_feature=4.6")  # it fits


def test_a_min_feature_on_a_scene_without_pores_is_refused():
    solid = scene_config({"name": "s", "cells": "SS\nSS", "pinned": [[0, 0], [10, 0]]})
    s = SimpleNamespace(
        trainer=SimpleNamespace(min_feature=1.0), part=SimpleNamespace(scale=2.0), scene=solid
    )
    with refused("trainer.min_feature=1 mm has no effect: scene s has no pores"):
        check_min_feature(s)
