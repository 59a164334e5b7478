"""A trained design as a file to make it from, and the numbers a fabricator checks first.

    python -m nma.export run=outputs/runs/translation/<date>_<time> format=svg|dxf|stl \\
        [scale=2] [thickness=10]

Writes <run>/export/design.<format> (or `output=`) and fabrication.json beside it, and prints the
report as one JSON line on stdout.  Lengths are in millimetres: `scale` millimetres per length unit
of the scene (the run's part.scale where it states one).
- svg: the outer boundary and every pore as one path of quadratic Bezier segments, exactly the
  design's curves (even-odd fill), the page sized in millimetres;
- dxf: one degree-2 SPLINE per closed curve, exactly the design's B-splines, drawing units
  millimetres;
- stl: the section (the curves through `samples` points per knot span) extruded to `thickness` mm.
The report: bounding box, material area, porosity (pore area over the area the outer boundary
encloses), the minimum ligament width, the narrowest material between two boundary curves (pore
to pore, or pore to outer boundary) and where it is, and (`states=true`, the default) whether the
design stays a physical object in every deformed state of its task's evaluation set
(evaluation_states: how many states are not, and why; nma/geometry/validity.py).  With
`load_cases=true` (translation runs), load_cases.png beside the file: the part deformed under the
paper's Fig. 5 loads (tension, compression, one-sided compression, at load_fraction x d_max) drawn
over the undeformed part, with the pointer's move and each state's validity in the report.  The
files and the report's numbers: nma.fabrication.
"""

from __future__ import annotations

import json
import dataclasses
import logging
import sys
from dataclasses import replace
from pathlib import Path

import hydra
import numpy as np
from omegaconf import DictConfig

from . import cli
from .cli import json_safe
from .config import CONF_DIR
from .fabrication import fabrication_report, write_dxf, write_stl, write_svg
from .geometry.outline import Outline
from .errors import ConfigError, SolverError
from .schema import ExportConfig, build, register
from .schema.effect import check_export

register()


def validate(cfg: DictConfig) -> ExportConfig:
    from .train.runs import load_run

    settings = build(ExportConfig, cfg)
    check_export(settings)  # what the user gave, before export() fills scale and thickness in
    own = Path(settings.run).resolve()
    if (
        settings.output
        and own in Path(settings.output).resolve().parents
        and (own / "export") not in Path(settings.output).resolve().parents
    ):
        raise ConfigError(
            f"output={settings.output} lies inside run={settings.run}, among the run's own files: "
            f"name a file elsewhere, or leave output unset (the run's export/ directory)"
        )
    # the run directory must hold a config and a checkpoint before any work
    run, _, _ = load_run(settings.run)
    if settings.load_cases and run.task.name != "translation":
        raise ConfigError(
            f"load_cases=true: the load cases (tension, compression, one-sided compression) are "
            f"the translation part's (the paper's Fig. 5); run={settings.run} is a "
            f"{run.task.name} run"
        )
    return settings


def trained_outline(run_dir) -> tuple[Outline, Path, object]:
    """The outline of a run's newest checkpointed geometry, in the scene's length units, that
    checkpoint's path and the run's settings."""
    from .runtime import configure_jax

    configure_jax()
    from .discretise import discretise
    from .schema import scene_from_config
    from .train.runs import load_run
    from .schema import Fidelity

    settings, params, path = load_run(run_dir)
    # the design nets themselves
    disc = discretise(scene_from_config(settings.scene), Fidelity(5, 2))
    return (
        Outline.of(disc.mesh, disc.reference_points(_geometry(disc, params, run_dir))),
        path,
        settings,
    )


def _geometry(disc, params, run_dir) -> dict:
    """A checkpoint's geometry parameters, checked against what the scene needs."""
    import jax.numpy as jnp

    geom = {}
    for name, init in disc.init_params().items():
        saved = np.asarray(params.get("geom", {}).get(name, init))
        if saved.shape != init.shape:
            raise ConfigError(
                f"run={run_dir}: geometry {name} has shape {saved.shape}, the scene needs "
                f"{init.shape}"
            )
        geom[name] = jnp.asarray(saved, init.dtype)
    return geom


def evaluation_states(run_dir) -> dict:
    """Does the design stay a physical object over its task's whole evaluation set?  The run's final
    evaluation (metrics.json) where it was made with the newest checkpoint, otherwise that
    evaluation solved again here (python -m nma.evaluate does the same at another fidelity)."""
    from .train.runs import load_run

    run = Path(run_dir)
    settings, _, path = load_run(run)
    step = int(path.stem.split("_")[-1])
    keys = (
        "invalid_states",
        "checked_states",
        "failed_solves",
        "min_J",
        "min_gap",
        "invalid_samples",
    )
    metrics = run / "metrics.json"
    try:
        logged = json.loads(metrics.read_text()) if metrics.is_file() else {}
    except (ValueError, UnicodeDecodeError):  # unreadable: solved again below, as without it
        logged = {}
    # a damaged file's are not taken on trust
    counts = ("invalid_states", "checked_states", "failed_solves")
    if (
        isinstance(logged, dict)
        and logged.get("step") == step
        and all(k in logged for k in keys)
        and all(type(logged[k]) is int and logged[k] >= 0 for k in counts)
    ):
        found, source = {k: logged[k] for k in keys}, f"the run's final evaluation ({metrics.name})"
    else:
        from .evaluate import evaluate_at

        found = evaluate_at(settings, run, settings.fidelity, settings.solver)
        found, source = {k: found[k] for k in keys}, f"solved again from {path.name}"
    fidelity = settings.fidelity
    # only states that were checked vouch for the design: a failed solve's were not
    failed, checked = found["failed_solves"], found["checked_states"]
    valid = found["invalid_states"] == 0 and checked > 0 and failed == 0
    unchecked = (
        f"{failed} of the evaluation set's solves failed: their states were not checked"
        if failed
        else None
        if checked
        else "no state was checked"
    )
    return {
        "valid": valid,
        **({"unchecked": unchecked} if unchecked else {}),
        **found,
        "step": step,
        "source": source,
        "fidelity": f"{fidelity.ctrl_per_patch} x {fidelity.quad_points}"
        + (f", grading {fidelity.grading:g}" if fidelity.grading != 1.0 else ""),
    }


# the paper's Fig. 5: the translation part pulled at both sides, pushed at both, pushed at one; the
# signs of its two actuations (left side moves by -d0 in x, right side by -d1)
LOAD_CASES = {
    "tension": (1.0, -1.0),
    "compression": (-1.0, 1.0),
    "one-sided compression": (0.0, 1.0),
}


def write_load_cases(
    run_dir, fraction: float, path: Path, scale: float, thickness: float, material=None
) -> dict:
    """The trained translation part deformed under LOAD_CASES (actuation fraction x d_max), each
    outline drawn over the undeformed part (the picture a maker compares with the printed part under
    the same loads), in millimetres; per case the pointer's displacement, the force each actuation
    pushes with (in N for a material with a physical unit: nma.units) and whether the state is
    physical.  `material` (a MaterialConfig): solved in it, the part as it is made, in place of the
    run's."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .geometry.validity import StateChecker
    from .resolve import material_params
    from .train.runs import load_run
    from .simulator import Simulator
    from .units import Units

    settings, params, _ = load_run(
        run_dir, None if material is None else dataclasses.asdict(material)
    )
    sim = Simulator.from_settings(settings)
    units = Units.of(replace(settings.part, scale=scale, thickness=thickness), settings.material)
    geom = _geometry(sim.disc, params, run_dir)
    X = np.asarray(sim.reference_points(geom))
    checker = StateChecker(sim.disc.mesh, X)
    mat = material_params(settings.material)
    rest = [
        scale * p
        for p in Outline.deformed(checker.loops, X, sim.disc.mesh.fidelity.grading).polylines(8)
    ]
    pointer0 = np.asarray(sim.tracked(X, np.zeros_like(X))["pointer"])
    fig, axes = plt.subplots(
        1, len(LOAD_CASES), figsize=(4.2 * len(LOAD_CASES), 4.6), sharex=True, sharey=True
    )
    cases = {}
    for ax, (name, signs) in zip(axes, LOAD_CASES.items()):
        d = fraction * settings.task.d_max * np.asarray(signs)
        for line in rest:
            ax.plot(*np.vstack([line, line[:1]]).T, color="#9a9a9a", lw=0.8)
        eq = sim.solve(geom, d, mat, throw=False)
        if not eq.converged:
            cases[name] = {
                "actuation": d.tolist(),
                "converged": False,
                "error": str(sim.failure(eq, d, mat)),
            }
            ax.set_title(f"{name}: solve failed", fontsize=9)
            continue
        state = checker.check(eq.u)
        moved = np.asarray(sim.tracked(X, eq.u)["pointer"]) - pointer0
        forces = np.asarray(sim.actuation_forces(X, eq.u, mat)).tolist()
        cases[name] = {
            "actuation": d.tolist(),
            "converged": True,
            "pointer_displacement_mm": (scale * moved).tolist(),
            "actuation_forces": forces,
            **units.physical("actuation_forces", forces, "force"),
            "valid": state.valid,
            "problems": state.problems(),
        }
        for line in Outline.deformed(
            checker.loops, X + np.asarray(eq.u), sim.disc.mesh.fidelity.grading
        ).polylines(8):
            ax.plot(
                *np.vstack([scale * line, scale * line[:1]]).T,
                color="#c0392b" if not state.valid else "#1f3fbf",
                lw=1.0,
            )
        ax.annotate(
            "",
            scale * (pointer0 + moved),
            scale * pointer0,
            arrowprops=dict(arrowstyle="->", color="#2ca02c", lw=1.5),
        )
        pushes = (
            "; pushes " + ", ".join(f"{f:+.3g} N" for f in cases[name]["actuation_forces_N"])
            if "actuation_forces_N" in cases[name]
            else ""
        )
        ax.set_title(
            f"{name}: d = {np.round(d, 2).tolist()}\npointer moves "
            f"({scale * moved[0]:+.2f}, {scale * moved[1]:+.2f}) mm{pushes}"
            + ("" if state.valid else ", NOT PHYSICAL"),
            fontsize=9,
        )
    for ax in axes:
        ax.set_aspect("equal")
        ax.set_xlabel("x [mm]")
    axes[0].set_ylabel("y [mm]")
    made = (
        ""
        if material is None
        else f", made of {material.name or material.law} (nu {material.nu:g})"
    )
    fig.suptitle(
        f"the learned part{made} under the paper's load cases\n(grey: undeformed; blue: deformed; "
        "red: deformed but not a physical object; green: the pointer's move)",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=150)
    plt.close(fig)
    return {
        "file": str(path),
        "fraction_of_d_max": fraction,
        "material": settings.material.record(),
        "units": units.record(),
        "cases": cases,
    }


def export(s: ExportConfig) -> dict:
    outline, checkpoint, run = trained_outline(s.run)
    s = replace(
        s,
        scale=s.scale or run.part.scale or 1.0,
        thickness=s.thickness or run.part.thickness or 10.0,
    )
    outline = outline.scaled(s.scale)
    path = (
        Path(s.output)
        if s.output
        else cli.unused_path(Path(s.run) / "export" / f"design.{s.format}")
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    report = fabrication_report(outline, s.samples)
    if s.format == "svg":
        write_svg(outline, path)
    elif s.format == "dxf":
        write_dxf(outline, path)
    else:
        report["thickness"] = s.thickness
        report["volume"] = write_stl(outline, path, s.thickness, s.samples)
    if s.states:
        report["evaluation_states"] = evaluation_states(s.run)
    if s.load_cases:
        report["load_cases"] = write_load_cases(
            s.run, s.load_fraction, path.parent / "load_cases.png", s.scale, s.thickness, s.material
        )
    # an earlier export's report stays
    fabrication = cli.unused_path(path.parent / "fabrication.json")
    result = {
        "file": str(path),
        "report": str(fabrication),
        "checkpoint": str(checkpoint),
        "format": s.format,
        "units": "mm",
        "scale_mm_per_unit": s.scale,
        **report,
    }
    fabrication.write_text(json.dumps(json_safe(result), indent=1, allow_nan=False))
    return result


@hydra.main(config_path=str(CONF_DIR), config_name="export", version_base="1.3")
def hydra_main(cfg: DictConfig) -> None:
    with cli.exit_codes(run_dir=Path(hydra.core.hydra_config.HydraConfig.get().runtime.output_dir)):
        result = export(validate(cfg))
    states = result.get("evaluation_states")
    if states and states["invalid_states"]:
        from .geometry.validity import describe

        logging.getLogger("nma.export").warning(
            "the design is not a physical object in every state of its task: %s",
            describe(states, states["invalid_samples"]),
        )
    if states and states.get("unchecked") and states["checked_states"]:
        logging.getLogger("nma.export").warning(
            "the design's states are not all checked: %s", states["unchecked"]
        )
    print(json.dumps(json_safe(result), allow_nan=False), flush=True)
    if states and not states["checked_states"]:  # the check asked for (states=true) says nothing
        with cli.exit_codes():
            raise SolverError(
                f"{result['file']} is written, but no state of its task's evaluation "
                f"set was checked: {states['unchecked']} ({states['failed_solves']} "
                f"failed solves; {result['report']} says so); states=false exports "
                f"without the check"
            )


def main() -> None:
    cli.preflight("export", lambda cfg, hydra_cfg, multirun: validate(cfg), sys.argv[1:])
    hydra_main()


if __name__ == "__main__":
    main()
