"""fidelity=auto: the choice from a measured front, its errors, and the fronts that ship with
nma."""

import dataclasses
import json
import logging
import re

import numpy as np
import pytest

from nma import config
from nma.fidelity import DATA, choose
from nma.errors import ConfigError
from nma.schema import Fidelity

SCENES = ["translation", "rotation_single", "rotation_double", "shape_matching", "digital_mnist"]


def row(ctrl, quad, seconds, error):
    return {
        "ctrl_per_patch": ctrl,
        "quad_points": quad,
        "dofs": 100 * ctrl,
        "forward_grad_seconds": {"median": seconds},
        "gradient_error": error,
        "gradient_cosine": 1 - error**2,
        "observable_error": error / 10,
        "on_front": True,
    }


@pytest.fixture
def known_front(tmp_path):
    body = {
        "scene": "toy",
        "rtol": 1e-10,
        "machine": {"cpus": 2},
        "reference": {"ctrl_per_patch": 14, "quad_points": 5, "rtol": 1e-12, "dofs": 1400},
        "settings": [
            row(5, 2, 0.08, 0.50),
            row(5, 3, 0.10, 0.35),
            row(5, 5, 0.15, 0.40),
            row(8, 3, 0.60, 0.12),
            row(8, 5, 1.10, 0.11),
            row(11, 4, 2.50, 0.03),
        ],
    }
    (tmp_path / "toy.json").write_text(json.dumps(body))
    return tmp_path


@pytest.mark.parametrize(
    "tolerance, expected",
    [(1.0, (5, 2)), (0.4, (5, 3)), (0.2, (8, 3)), (0.115, (8, 5)), (0.05, (11, 4))],
)
def test_auto_picks_the_fastest_setting_within_the_tolerance(known_front, tolerance, expected):
    choice = choose("toy", tolerance, known_front)
    assert (choice.fidelity.ctrl_per_patch, choice.fidelity.quad_points) == expected
    assert choice.fidelity.tolerance == tolerance
    assert choice.measured["gradient_error"] <= tolerance
    assert f"{expected[0]} control points per patch, {expected[1]} Gauss points" in choice.reason


def test_auto_refuses_a_tolerance_below_the_front_and_a_scene_without_one(known_front):
    with pytest.raises(
        ConfigError, match=r"fidelity.tolerance must be at least 0.03 .*11 control points"
    ):
        choose("toy", 0.01, known_front)
    with pytest.raises(
        ConfigError, match="no measured front for scene other.*fidelity_study.py --scenes other"
    ):
        choose("other", 0.5, known_front)


def held(scene="translation", **change):
    from nma.schema import scene_from_config

    return scene_from_config({**config.load("scene", scene), **change})


def test_auto_reads_the_front_of_the_scene_held_as_the_run_holds_it(known_front):
    """A front's errors are of the body held as it was measured: the scene as shipped reads
    <scene>.json, its well-posed variant (no pins) <scene>_unpinned.json, and a scene held otherwise
    (one pin, a support added) has no front: refused, naming how it is held and how the fronts
    were."""
    from nma.fidelity import holds
    from nma.geometry.scene import Support

    paper = json.loads((known_front / "toy.json").read_text())
    shipped, unpinned = held(), held(pinned=[])
    for name, spec, rows in (
        ("toy.json", shipped, paper["settings"]),
        ("toy_unpinned.json", unpinned, [row(5, 2, 0.08, 0.30), row(8, 3, 0.60, 0.05)]),
    ):
        body = {**paper, "holds": holds(spec), "settings": rows}
        (known_front / name).write_text(json.dumps(body))
    toy = lambda spec: dataclasses.replace(spec, name="toy")
    assert holds(shipped)["pinned"] and not holds(unpinned)["pinned"]
    assert (
        choose(toy(shipped), 0.4, known_front).fidelity.ctrl_per_patch,
        choose(toy(unpinned), 0.4, known_front).fidelity.ctrl_per_patch,
    ) == (5, 5)
    # paper front: 5 x 3 at 0.35
    assert choose(toy(shipped), 0.4, known_front).fidelity.quad_points == 3
    # its own: 5 x 2 at 0.30
    assert choose(toy(unpinned), 0.4, known_front).fidelity.quad_points == 2
    assert "toy_unpinned.json" in choose(toy(unpinned), 0.1, known_front).reason
    # by name: the scene as shipped
    assert choose("toy", 0.4, known_front).fidelity.quad_points == 3
    # the same body listed in another order is held the same
    assert (
        choose(
            toy(
                dataclasses.replace(
                    shipped, pinned=shipped.pinned[::-1], groups=shipped.groups[::-1]
                )
            ),
            0.4,
            known_front,
        ).fidelity.quad_points
        == 3
    )
    # held otherwise: refused, naming what differs from each front and how this run holds it
    one_pin = held(pinned=[[0, 0]])
    with pytest.raises(
        ConfigError,
        match=r"no front for scene toy held as this run holds it.*\(toy.json: "
        r"scene.pinned=\[\[0.0, 0.0\], \[0.0, 25.0\].*; toy_unpinned.json: "
        r"scene.pinned=\[\]; this run: scene.pinned=\[\[0.0, 0.0\]\]\)",
    ):
        choose(toy(one_pin), 0.4, known_front)
    supported = dataclasses.replace(unpinned, supports=(Support(((0.0, 0.0), (5.0, 0.0)), (1,)),))
    with pytest.raises(
        ConfigError,
        match=r"toy_unpinned.json: scene.supports=\[\]; this run: scene.pinned=\[\], "
        r"scene.supports=\[\[\[0.0, 0.0\], \[5.0, 0.0\], \[1\]\]\]",
    ):
        choose(toy(supported), 0.4, known_front)
    moved = dataclasses.replace(
        unpinned,
        groups=(
            dataclasses.replace(unpinned.groups[0], direction=(1.0, 0.0)),
            *unpinned.groups[1:],
        ),
    )
    with pytest.raises(
        ConfigError, match=r"toy_unpinned.json: scene.groups \(the actuated segments\)="
    ):
        choose(toy(moved), 0.4, known_front)
    # a front measured before fronts recorded how the scene was held is not read for a scene
    (known_front / "toy_unpinned.json").write_text(json.dumps(paper))
    with pytest.raises(ConfigError, match="toy_unpinned.json records no holds"):
        choose(toy(unpinned), 0.4, known_front)


def test_a_trained_run_keeps_the_setting_auto_chose_for_it(tmp_path):
    """Re-evaluating or exporting a run (load_run) and resuming it take the setting its checkpoint
    records auto chose, not what today's fronts would pick; its record says so where they pick
    otherwise."""
    from nma.fidelity import choice_of
    from nma.train.runs import chosen_fidelity, fingerprint, validate
    from conftest import compose_cfg

    cfg = compose_cfg("task=translation", "fidelity=auto", "fidelity.tolerance=0.6", "logger=none")
    today = validate(cfg)
    raw = {
        "config": json.dumps(
            fingerprint(
                dataclasses.replace(
                    today,
                    fidelity=dataclasses.replace(today.fidelity, ctrl_per_patch=11, quad_points=2),
                )
            )
        )
    }
    assert (
        chosen_fidelity(raw) == (11, 2)
        and chosen_fidelity(
            {
                "config": json.dumps(
                    fingerprint(validate(compose_cfg("task=translation", "logger=none")))
                )
            }
        )
        is None
    )
    trained = validate(cfg, chosen_fidelity(raw))
    assert (
        trained.fidelity.ctrl_per_patch,
        trained.fidelity.quad_points,
        trained.fidelity.tolerance,
    ) == (11, 2, 0.6)
    assert (today.fidelity.ctrl_per_patch, today.fidelity.quad_points) != (11, 2)
    # a run resumed in its directory keeps it too; a new one there (trainer.resume=false) chooses
    # afresh
    from nma.run import validate_in
    from nma.train import checkpoint

    run_dir = tmp_path / "run"
    checkpoint.save(run_dir / "checkpoints", 5, {"step": 5, **raw})
    resumed = compose_cfg(
        "task=translation",
        "fidelity=auto",
        "fidelity.tolerance=0.6",
        "logger=none",
        "trainer.resume=true",
    )
    assert validate_in(resumed, run_dir)[0].fidelity == trained.fidelity
    assert validate_in(cfg, run_dir)[0].fidelity == today.fidelity
    record = choice_of(trained.fidelity, held()).record()
    assert record["measured"] == {} and "when the run was trained" in record["reason"]
    assert choice_of(today.fidelity, held()).reason == choose(held(), 0.6).reason


WELL_POSED = {
    "_unpinned": {"pinned": []},
    "_unpinned_round": {"pinned": [], "round_pore_corners": True},
}


@pytest.mark.parametrize("variant", [*SCENES, *(s + v for v in WELL_POSED for s in SCENES)])
def test_every_scene_ships_its_measured_front(variant):
    """make study-fidelity wrote these, for the scenes as shipped and their well-posed variants
    (--unpinned, with sharp and with round pore corners): each records how its scene was held, the
    paper's setting is measured, errors fall with refinement at 5 Gauss points, and the marked front
    is exactly the Pareto-optimal set of the rows."""
    from nma.fidelity import holds

    scene = next(
        (
            variant.removesuffix(v)
            for v in sorted(WELL_POSED, key=len, reverse=True)
            if variant.endswith(v)
        ),
        variant,
    )
    body = json.loads((DATA / f"{variant}.json").read_text())
    assert body["scene"] == scene
    assert body["holds"] == holds(held(scene, **WELL_POSED.get(variant[len(scene) :], {})))
    rows = {(r["ctrl_per_patch"], r["quad_points"]): r for r in body["settings"]}
    assert (5, 5) in rows and (8, 5) in rows and (11, 5) in rows
    assert (
        rows[(11, 5)]["gradient_error"]
        < rows[(8, 5)]["gradient_error"]
        < rows[(5, 5)]["gradient_error"]
    )
    pts = [(r["forward_grad_seconds"]["median"], r["gradient_error"]) for r in body["settings"]]
    for r, (t, e) in zip(body["settings"], pts):
        dominated = any(t2 <= t and e2 <= e and (t2, e2) != (t, e) for t2, e2 in pts)
        assert r["on_front"] == (not dominated)
    assert body["reference"]["ctrl_per_patch"] > max(k[0] for k in rows)


def test_a_run_with_fidelity_auto_discretises_at_the_chosen_setting(caplog):
    """Validation resolves the front's choice once, the settings (and so the checkpoint's
    fingerprint, which a resume compares) carry the chosen setting, the discretisation takes it as
    given, and the run's metrics record it and why; a tolerance no setting meets fails before any
    work."""
    from nma.fidelity import choice_of
    from nma.discretise import discretise
    from nma.geometry.options import Resolution
    from nma.schema import scene_from_config
    from nma.train.runs import fidelity_record, fingerprint, validate
    from conftest import compose_cfg

    with caplog.at_level(logging.INFO, logger="nma.fidelity"):
        settings = validate(
            compose_cfg(
                "task=translation", "fidelity=auto", "fidelity.tolerance=0.6", "logger=none"
            )
        )
    expected = choose("translation", 0.6)
    # the front picks the discretisation; the material (auto) the barrier: off at the paper's nu 0.3
    assert (
        settings.fidelity == dataclasses.replace(expected.fidelity, inversion_barrier=0.0)
        and expected.reason in caplog.text
    )
    assert (
        fingerprint(settings)["fidelity"].get("ctrl_per_patch", 5)
        == expected.fidelity.ctrl_per_patch
    )
    assert choice_of(settings.fidelity, "translation").reason == expected.reason
    disc = discretise(scene_from_config(settings.scene), settings.fidelity)
    assert disc.mesh.fidelity == Resolution.of(expected.fidelity)
    record = fidelity_record(disc, settings.fidelity)
    assert record["auto"]["tolerance"] == 0.6 and record["dofs"] == disc.boundary.n_dofs
    assert (record["ctrl_per_patch"], record["quad_points"]) == (
        expected.fidelity.ctrl_per_patch,
        expected.fidelity.quad_points,
    )
    with pytest.raises(ConfigError, match="fidelity.tolerance must be at least"):
        validate(
            compose_cfg(
                "task=translation", "fidelity=auto", "fidelity.tolerance=1e-9", "logger=none"
            )
        )
    # the well-posed variant reads its own front; a scene held otherwise has none, and stops before
    # any work
    settings = validate(
        compose_cfg(
            "task=translation",
            "fidelity=auto",
            "fidelity.tolerance=0.6",
            "scene.pinned=[]",
            "logger=none",
        )
    )
    assert settings.fidelity == dataclasses.replace(
        choose(held(pinned=[]), 0.6).fidelity, inversion_barrier=0.0
    )
    assert "translation_unpinned.json" in choice_of(settings.fidelity, held(pinned=[])).reason
    with pytest.raises(
        ConfigError, match="no front for scene translation held as this run holds it"
    ):
        validate(
            compose_cfg("task=translation", "fidelity=auto", "scene.pinned=[[0,0]]", "logger=none")
        )
    # round pore corners converge faster than sharp ones: the well-posed variant with them reads its
    # own front, and the pinned scene with them, measured neither way, is refused
    settings = validate(
        compose_cfg(
            "task=translation",
            "fidelity=auto",
            "fidelity.tolerance=0.6",
            "scene.pinned=[]",
            "scene.round_pore_corners=true",
            "logger=none",
        )
    )
    rounded = held(pinned=[], round_pore_corners=True)
    assert "translation_unpinned_round.json" in choice_of(settings.fidelity, rounded).reason
    with pytest.raises(
        ConfigError,
        match=r"translation.json: scene.round_pore_corners=false; .*this run: .*"
        r"scene.round_pore_corners=true\)",
    ):
        validate(
            compose_cfg(
                "task=translation", "fidelity=auto", "scene.round_pore_corners=true", "logger=none"
            )
        )
    assert config.load("fidelity", "auto")["tolerance"] > 0
    assert Fidelity().tolerance is None  # presets are what they say


REPRO = {
    "translation": "repro_translation",
    "shape_matching": "repro_shape_matching",
    "digital_mnist": "repro_mnist_lookup",
}


@pytest.mark.parametrize("scene", SCENES)
def test_fidelity_scene_is_the_scenes_own_setting_measured_no_worse_than_the_papers(scene):
    """fidelity=scene (the default) takes the scene's `fidelity` field where it states one: its
    reproduction's model (fidelity and contact), whose measured gradient error (the shipped front)
    is no larger than the paper's 5 x 5; the rotations state none (their reproductions' 5 x 2 is a
    first stage, refined at finer fidelities with contact), so they get the paper's.  Translation's
    5 x 2 trains physical states with the inversion penalty, and so the penalty is on wherever its
    reproduction has it."""
    from nma.train.runs import absent_means, fingerprint, validate
    from conftest import compose_cfg

    own = validate(compose_cfg(f"task={scene}", "logger=none"))
    states = config.load("scene", scene).get("fidelity")
    assert bool(states) == (scene in REPRO)
    if states:
        repro = validate(compose_cfg(f"experiment={REPRO[scene]}"))
        assert (own.fidelity, own.contact.enabled) == (repro.fidelity, repro.contact.enabled)
        if repro.trainer.inversion_penalty:  # a model trained with the penalty is stated with it
            assert own.trainer.inversion_penalty == repro.trainer.inversion_penalty
        assert (own.fidelity.ctrl_per_patch, own.fidelity.quad_points) == (5, states["quad_points"])
        rows = {
            (r["ctrl_per_patch"], r["quad_points"]): r["gradient_error"]
            for r in json.loads((DATA / f"{scene}.json").read_text())["settings"]
        }
        assert rows[(own.fidelity.ctrl_per_patch, own.fidelity.quad_points)] <= rows[(5, 5)]
    else:
        assert (own.fidelity.ctrl_per_patch, own.fidelity.quad_points) == (5, 5)
    paper = validate(compose_cfg(f"task={scene}", "fidelity=paper", "logger=none"))
    assert (paper.fidelity.ctrl_per_patch, paper.fidelity.quad_points) == (5, 5)
    # the resolved setting is the run's record; the scene's field is not compared again on resume
    assert (
        "fidelity" not in fingerprint(paper)["scene"]
        and "quad_points" not in fingerprint(paper)["fidelity"]
    )
    assert absent_means(paper)["fidelity.quad_points"] == 5  # the record's absence: the default, 5


def test_fidelity_scene_leaves_what_the_command_sets_and_checks_the_scenes_field():
    from nma.train.runs import validate
    from conftest import compose_cfg

    half = validate(
        compose_cfg("task=shape_matching", "fidelity.ctrl_per_patch=8", "logger=none")
    ).fidelity
    # the scene's quad_points, the command's control points
    assert (half.ctrl_per_patch, half.quad_points) == (8, 2)
    with pytest.raises(
        ConfigError,
        match=re.escape("scene.fidelity.quad_points must be an integer in [2, 10], got 1"),
    ):
        validate(
            compose_cfg("task=shape_matching", "scene.fidelity={quad_points:1}", "logger=none")
        )
    from nma.schema import scene_config

    for own, message in [
        ({"ctrl_per_patch": 6}, "scene.fidelity.ctrl_per_patch must be 3k + 2"),
        (
            {"grading": 2},
            "scene.fidelity may set ctrl_per_patch and quad_points only, not ['grading']",
        ),
    ]:
        with pytest.raises(ConfigError, match=re.escape(message)):
            scene_config({**config.load("scene", "translation"), "fidelity": own})


def test_random_design_stays_in_its_box_with_convex_cells():
    from nma.geometry.design import MIN_TURN
    from nma.schema import scene_from_config
    from nma.geometry.design import make_design

    design = make_design(scene_from_config(config.load("scene", "shape_matching")))
    params = design.random_params(np.random.default_rng(3))
    for k, (lo, hi) in design.bounds().items():
        assert np.all(np.asarray(params[k]) >= lo) and np.all(np.asarray(params[k]) <= hi)
        assert np.ptp(np.asarray(params[k])) > 0  # non-uniform
    assert float(np.min(design.corner_turns(params))) >= MIN_TURN


def test_reference_check_on_a_blunter_random_design(monkeypatch, tmp_path):
    """--spread draws the same random design closer to the middle of the box (the radii's deviations
    from the middle scale with it, so pore corners are blunter), names its report for it, and a
    spread outside (0, 1] is refused before any work."""
    from experiments import fidelity_study as study
    from nma.geometry.design import make_design
    from nma.schema import scene_from_config

    class Sim:  # what study_draws reads of a simulator
        disc = type(
            "Disc",
            (),
            {"design": make_design(scene_from_config(config.load("scene", "rotation_single")))},
        )()
        n_actuations = 1

    lo, hi = Sim.disc.design.bounds()["radii"]
    (wide, d_wide), (blunt, d_blunt) = (
        study.study_draws(Sim, 4.0, 3, spread=s) for s in (0.6, 0.3)
    )
    np.testing.assert_allclose(
        np.asarray(blunt["radii"]) - (lo + hi) / 2,
        (np.asarray(wide["radii"]) - (lo + hi) / 2) / 2,
        atol=1e-12,
    )
    np.testing.assert_array_equal(d_blunt, d_wide)  # the same actuations
    assert (
        study.variant("rotation_single", 3.0, True, 0.3)
        == "rotation_single_unpinned_graded3_spread0.3"
    )
    assert study.variant("rotation_single", 3.0, True) == "rotation_single_unpinned_graded3"
    monkeypatch.setattr(
        "sys.argv",
        ["fidelity_study.py", "--convergence", "--spread", "1.5", "--out", str(tmp_path)],
    )
    with pytest.raises(SystemExit):
        study.main()
    assert not list(tmp_path.iterdir())


def test_reference_check_at_shorter_actuations(monkeypatch, tmp_path):
    """--actuation draws the same design and the same actuation directions, shorter (uniform in
    [-a d_max, a d_max]; the default 0.5 is the study's own draws), names its report for it, and an
    actuation outside (0, 1] is refused before any work."""
    from experiments import fidelity_study as study
    from nma.geometry.design import make_design
    from nma.schema import scene_from_config

    class Sim:  # what study_draws reads of a simulator
        disc = type(
            "Disc",
            (),
            {"design": make_design(scene_from_config(config.load("scene", "shape_matching")))},
        )()
        n_actuations = 12

    (geom, d), (same_geom, d_half) = (
        study.study_draws(Sim, 3.0, 2, actuation=a) for a in (0.5, 0.25)
    )
    np.testing.assert_array_equal(np.asarray(same_geom["radii"]), np.asarray(geom["radii"]))
    np.testing.assert_allclose(d_half, d / 2, atol=1e-12)
    assert np.abs(d).max() <= 1.5 and np.abs(d).max() > 1.0  # 24 draws uniform in [-1.5, 1.5]
    assert (
        study.variant("shape_matching", 3.0, True, actuation=0.25)
        == "shape_matching_unpinned_graded3_actuation0.25"
    )
    for bad in ("0", "1.5"):
        monkeypatch.setattr(
            "sys.argv",
            ["fidelity_study.py", "--convergence", "--actuation", bad, "--out", str(tmp_path)],
        )
        with pytest.raises(SystemExit):
            study.main()
    assert not list(tmp_path.iterdir())


def test_a_scene_whose_reference_check_fails_does_not_stop_the_others(monkeypatch, tmp_path):
    """make study-wellposed checks every scene in turn: one whose finer levels do not solve (its
    child process fails) is named at the end, in a non-zero exit, after the others' reports are
    written."""
    import subprocess
    from pathlib import Path

    from experiments import fidelity_study as study

    reported = []

    def child(cmd):  # the child process: shape matching fails, the others write a result
        scene = cmd[cmd.index("--scenes") + 1]
        if scene != "shape_matching":
            Path(cmd[cmd.index("--result") + 1]).write_text(json.dumps({"scene": scene}))
        return subprocess.CompletedProcess(cmd, int(scene == "shape_matching"))

    monkeypatch.setattr(study.subprocess, "run", child)
    monkeypatch.setattr(
        study, "convergence_report", lambda result, out: reported.append(result["scene"]) or ""
    )
    monkeypatch.setattr(
        "sys.argv",
        [
            "fidelity_study.py",
            "--convergence",
            "--scenes",
            "translation",
            "shape_matching",
            "rotation_double",
            "--out",
            str(tmp_path),
        ],
    )
    with pytest.raises(SystemExit, match="no reference check for shape_matching"):
        study.main()
    assert reported == ["translation", "rotation_double"]


@pytest.mark.parametrize("orders", [(2.0,), (1.0, 0.5)])
def test_refinement_recovers_order_and_richardson_limit_of_a_manufactured_sequence(
    orders, tmp_path
):
    """q(h) = q* + C sum_i h^p_i with known q*, C, p_i (h = 1 / knot spans, spans = control points -
    2). One power law: the reference check must find its order from both triples of the ladder 8 ->
    11 -> 14 -> 17, and Richardson's limit q* and the finest level's error.  Two (h + sqrt h, as a
    solution with a boundary singularity converges): the order must be seen falling along the
    ladder, the sign that it is not yet in the asymptotic range."""
    from experiments import fidelity_study as study

    rng = np.random.default_rng(0)
    limit = {"observable": rng.normal(size=(2, 6)), "radii": rng.normal(size=(2, 9))}
    coeff = {k: rng.normal(size=v.shape) for k, v in limit.items()}
    levels = []
    for c in (8, 11, 14, 17):
        q = {k: limit[k] + coeff[k] * sum((1.0 / (c - 2)) ** p for p in orders) for k in limit}
        levels.append(
            {
                "ctrl_per_patch": c,
                "_outputs": q["observable"],
                "_grads": [{"radii": g} for g in q["radii"]],
            }
        )
    summary, limits = study.refinement(levels)
    assert summary["spans"] == [6, 9, 12, 15]
    for name, key in (("observable", "observable"), ("gradient radii", "radii")):
        found = summary["quantities"][name]
        assert len(found["differences"]) == 3 and len(found["orders"]) == 2
        if len(orders) == 1:
            np.testing.assert_allclose(found["orders"], [orders[0]] * 2, rtol=1e-6)
            np.testing.assert_allclose(limits[name], limit[key], rtol=1e-8, atol=1e-10)
            finest = study.quantities(levels[-1])[name]
            assert found["finest_error"] == pytest.approx(
                np.max(study.distance(name, finest, limit[key], finest)), rel=1e-6
            )
            # the study's own check (8 -> 11 -> 14 against its reference) is the three-level case
            three = study.refinement(levels[:3])[0]["quantities"][name]
            assert three["orders"] == pytest.approx([orders[0]], rel=1e-6)
        else:
            assert orders[1] < found["orders"][1] < found["orders"][0] < orders[0]
    # the report's files are named for the scene's variant, whatever quantities it lists
    for v in summary["quantities"].values():
        v["error"] = {
            "14x5": {
                "vs_reference": 0.0,
                "vs_limit": 0.1,
                "cosine_vs_reference": 1.0,
                "cosine_vs_limit": 0.99,
            }
        }
    result = {
        "scene": "translation",
        "grading": 2.5,
        "unpinned": True,
        "draws": 2,
        "quad_points": 5,
        "dofs": {"14x5": 34088},
        "forward_grad_seconds": {"14x5": {"median": 1.0}},
        **summary,
    }
    assert "| gradient radii |" in study.convergence_report(result, tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "translation_unpinned_graded2.5.convergence.json",
        "translation_unpinned_graded2.5.convergence.md",
    ]


def test_reference_check_names_impossible_states_and_orders_over_physical_draws(
    monkeypatch, tmp_path
):
    """A draw whose state is not physical at one level of the ladder (as the solver reports it
    converged) is named in the report, and the orders are taken again over the draws physical at
    every level: here draw 0 converges at order 2 and draw 1, the non-physical one, at order 0.5, so
    over all draws the finest triple's order is near 0.5 and over the physical draw exactly 2."""
    from experiments import fidelity_study as study

    rng = np.random.default_rng(0)
    limit, coeff = rng.normal(size=(2, 5)), rng.normal(size=(2, 5))
    order = np.array([[2.0], [0.5]])

    def measure(scene, setting, draws, **model):
        c = setting[0]
        q = limit + coeff * (1.0 / (c - 2)) ** order
        bad = [
            {
                "draw": 1,
                "min_J": -0.1,
                "problems": ["material inverted (det F down to -0.1 near (3, 4)) in 2 elements"],
            }
        ]
        return {
            "ctrl_per_patch": c,
            "quad_points": setting[1],
            "dofs": 100 * c,
            "failed_draws": [],
            "nonphysical_draws": bad if c == 17 else [],
            "forward_grad_seconds": {"median": 1.0},
            "_outputs": q[:, :2],
            "_grads": [{"radii": g} for g in q[:, 2:]],
        }

    monkeypatch.setattr(study, "measure", measure)
    # a toy gradient, not the scene's radii
    monkeypatch.setattr(study, "radii_by_corner", lambda result: None)
    result = study.richardson("translation", 2, ladder=(11, 14, 17, 20), checked=[(5, 2)])
    assert result["nonphysical"] == {"17x5": measure("", (17, 5), 2)["nonphysical_draws"]}
    assert result["quantities"]["gradient radii"]["orders"][-1] < 1.0
    assert result["physical"]["draws"] == [0]
    np.testing.assert_allclose(
        result["physical"]["quantities"]["gradient radii"]["orders"], [2.0, 2.0], rtol=1e-6
    )
    text = study.convergence_report(result, tmp_path)
    assert "- 17x5, draw 1: material inverted" in text and "(1 of 2: 0)" in text


def test_reference_check_leaves_out_a_draw_whose_solve_stops_short(monkeypatch, tmp_path):
    """A draw whose solve stops short at one level (the solver says so) has no answer to compare: it
    is left out of every level, and the check goes on over the others, the report naming it (here
    draw 2 fails at 20 x 5, draw 1 folds at 17 x 5, draw 0 converges at order 2); where no draw
    solves at every level there is no check, and the error says which solves stopped."""
    from experiments import fidelity_study as study

    rng = np.random.default_rng(1)
    limit, coeff = rng.normal(size=(3, 5)), rng.normal(size=(3, 5))
    order = np.array([[2.0], [0.5], [1.0]])
    stop = {"draw": 2, "load_reached": 0.79, "residual": 2.5e-3}

    def measure(scene, setting, draws, failing=(2,), **model):
        c = setting[0]
        q = limit + coeff * (1.0 / (c - 2)) ** order
        q[2] = np.nan if c == 20 else q[2]  # what a stopped solve leaves
        bad = [{"draw": 1, "min_J": -0.1, "problems": ["pore at (2.5, 7.5) crosses itself"]}]
        return {
            "ctrl_per_patch": c,
            "quad_points": setting[1],
            "dofs": 100 * c,
            "failed_draws": [{**stop, "draw": i} for i in failing] if c == 20 else [],
            "nonphysical_draws": bad if c == 17 else [],
            "forward_grad_seconds": {"median": 1.0},
            "_outputs": q[:, :2],
            "_grads": [{"radii": g} for g in q[:, 2:]],
        }

    monkeypatch.setattr(study, "measure", measure)
    # a toy gradient, not the scene's radii
    monkeypatch.setattr(study, "radii_by_corner", lambda result: None)
    result = study.richardson("translation", 3, ladder=(11, 14, 17, 20), checked=[(5, 2)])
    assert result["solved_draws"] == [0, 1] and result["failed"] == {"20x5": [stop]}
    assert np.all(np.isfinite(result["quantities"]["gradient radii"]["differences"]))
    assert result["physical"]["draws"] == [0]
    np.testing.assert_allclose(
        result["physical"]["quantities"]["gradient radii"]["orders"], [2.0, 2.0], rtol=1e-6
    )
    text = study.convergence_report(result, tmp_path)
    assert (
        "- 20x5, draw 2: load reached 0.790, residual 0.0025" in text
        and "2 of 3 draws kept: 0, 1" in text
    )
    assert "- 17x5, draw 1: pore at (2.5, 7.5) crosses itself" in text

    monkeypatch.setattr(study, "measure", lambda *a, **k: measure(*a, failing=(0, 1, 2), **k))
    with pytest.raises(RuntimeError, match="no draw solves at every level"):
        study.richardson("translation", 3, ladder=(11, 14, 17, 20), checked=[(5, 2)])


def test_fronts_report_names_the_states_that_cannot_exist(tmp_path):
    """The fronts study's report lists a setting's states that the solver converged to but that
    cannot exist (their errors stay in its table), and says nothing of the kind when every state is
    physical."""
    from experiments import fidelity_study as study

    def setting(ctrl, quad, seconds, error, nonphysical=()):
        t = {"min": seconds, "median": seconds}
        return {
            "ctrl_per_patch": ctrl,
            "quad_points": quad,
            "rtol": study.DEFAULT_RTOL,
            "dofs": 100 * ctrl,
            "forward_seconds": t,
            "forward_grad_seconds": t,
            "peak_memory_mb": 100.0,
            "observable_error": error,
            "gradient": {"radii": {"relative_error": error, "cosine": 1 - error}},
            "gradient_error": error,
            "gradient_cosine": 1 - error,
            "nonphysical_draws": list(nonphysical),
        }

    folded = {"draw": 2, "min_J": -0.05, "problems": ["pore at (2.5, 17.5) crosses itself"]}
    result = {
        "scene": "translation",
        "unpinned": False,
        "draws": 3,
        "convergence": None,
        "reference": {
            "ctrl_per_patch": 14,
            "quad_points": 5,
            "rtol": 1e-12,
            "dofs": 1400,
            "forward_grad_seconds": {"median": 5.0},
        },
        "settings": [setting(5, 2, 0.1, 0.2, [folded]), setting(8, 2, 0.3, 0.08)],
    }
    study.report(result, tmp_path)
    text = (tmp_path / "translation.md").read_text()
    assert (
        "cannot exist" in text
        and "- 5 x 2, tolerance 1e-10, draw 2: pore at (2.5, 17.5) crosses itself" in text
    )
    result["settings"][0]["nonphysical_draws"] = []
    study.report(result, tmp_path)
    assert "cannot exist" not in (tmp_path / "translation.md").read_text()


def test_radii_gradient_split_by_corner_finds_each_groups_order():
    """A manufactured radii gradient on the single rotation's study design, whose entries converge
    at order 1 at pore corners sharper than 45 deg, 1.5 at the other corners and 2 along the sides:
    each group of the split must show its own order exactly (an entry in the wrong group would mix
    two power laws), and the groups' shares of the finest difference add up to 1."""
    from experiments import fidelity_study as study
    from nma.geometry.design import GridDesign
    from nma.schema import scene_from_config

    design = GridDesign.from_spec(scene_from_config(study.scene_config("rotation_single", True)))
    angle = design.pore_corner_angles(design.random_params(np.random.default_rng(0), study.SPREAD))
    corner = np.zeros((len(design.porous), 16), bool)
    corner[:, ::4] = True
    order = np.full(corner.shape, 2.0)
    order[:, ::4] = np.where(angle < 45.0, 1.0, 1.5)
    order = order.ravel()
    rng = np.random.default_rng(1)
    limit, coeff = rng.normal(size=(2, order.size)), rng.normal(size=(2, order.size))
    spans = [12, 15, 18, 21]
    values = {f"{s + 2}x5": (limit + coeff * (1.0 / s) ** order).tolist() for s in spans}
    result = {
        "scene": "rotation_single",
        "unpinned": True,
        "spans": spans,
        "values": {"gradient radii": values},
    }
    groups = {g["group"]: g for g in study.radii_by_corner(result)}
    assert set(groups) == {
        "corner radii, pore angle 0-45 deg",
        "corner radii, pore angle 45-90 deg",
        "corner radii, pore angle 90-180 deg",
        "corner radii, pore angle 180-360 deg",
        "side radii next to a corner",
        "side radii mid-side",
    }
    for name, p in (("0-45", 1.0), ("45-90", 1.5), ("90-180", 1.5), ("180-360", 1.5)):
        np.testing.assert_allclose(
            groups[f"corner radii, pore angle {name} deg"]["orders"], [p, p], rtol=1e-6
        )
    for name in ("side radii next to a corner", "side radii mid-side"):
        np.testing.assert_allclose(groups[name]["orders"], [2.0, 2.0], rtol=1e-6)
    assert sum(g["radii"] for g in groups.values()) == order.size
    assert sum(g["share_of_finest_difference"] for g in groups.values()) == pytest.approx(1.0)
    assert study.radii_by_corner({**result, "values": {}}) is None  # nothing per level: no split


def test_error_map_finds_each_regions_order_of_a_manufactured_ladder():
    """experiments/error_map.py's arithmetic: deformed states x_m = X + h_m^p f(X) with one order p1
    within the radius of a segment's end and another p2 elsewhere (h = 1 / spans, spans = control
    points - 2) must give back p1 near the ends, p2 elsewhere, on both triples of the ladder."""
    from experiments import error_map

    s = np.linspace(0.0, 10.0, 21)
    X = np.stack(np.meshgrid(s, s, indexing="ij"), axis=-1)[None]  # one patch, (1, S, S, 2)
    ends = [[0.0, 0.0], [10.0, 10.0]]
    r = np.min(np.linalg.norm(X[..., None, :] - np.asarray(ends), axis=-1), axis=-1)
    near = r < 2.5
    field = np.where(near[..., None], [3.0, -1.0], [0.5, 2.0]) * (1.0 + 0.1 * X)
    p1, p2, ladder = 0.7, 1.6, [11, 14, 17, 20]
    levels = {
        m: {
            "reference": X,
            "deformed": X
            + field * np.where(near, (1.0 / (m - 2)) ** p1, (1.0 / (m - 2)) ** p2)[..., None],
        }
        for m in ladder
    }
    found = error_map.regions({"levels": levels, "ends": ends}, ladder, 2.5)
    rows = found["rows"]
    np.testing.assert_allclose(rows["rms near the segments' ends"]["orders"], [p1, p1], rtol=1e-6)
    np.testing.assert_allclose(rows["rms elsewhere"]["orders"], [p2, p2], rtol=1e-6)
    assert found["near_fraction"] == pytest.approx(near.mean())
    assert (
        len(rows["max"]["differences"]) == 3
        and rows["max"]["differences"][0] > rows["max"]["differences"][-1]
    )
