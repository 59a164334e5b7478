"""Does a trained design survive refinement?  A run re-evaluated at another discretisation.

    python -m nma.evaluate run=outputs/runs/translation/<date>_<time> fidelity=fine
    python -m nma.evaluate run=... fidelity.ctrl_per_patch=11 fidelity.quad_points=4

Takes the run's newest checkpoint (network and geometry), evaluates the task's evaluation set (or
eval_subset=N samples of it, evenly spaced, for a set too large to solve finely) at the run's own
training fidelity and at the one asked for, with the same code and the run's own solver settings
(solver=<backend> and solver.* choose others), and writes both side by side into
<run>/evaluate/<ctrl>x<quad>[_contact][_<N>_samples].json (and one JSON line on stdout): the metric,
its per-sample values, failed solves, how many states are not physical objects
(nma/geometry/validity.py), the change, and the DOFs of each discretisation.  A design that only
works in the coarse model shows here as a metric that grows under refinement.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from pathlib import Path

import hydra
import numpy as np
from omegaconf import DictConfig

from . import cli
from .config import CONF_DIR
from .errors import SolverError
from .schema import EvaluateConfig, build, register

register()


def validate(cfg: DictConfig) -> EvaluateConfig:
    """The checked settings, resolved beside the run's own: what they leave to auto is as the run
    solved, and contact=auto is as the run's scene says (nma.resolve)."""
    from .registry import LINEAR_SOLVERS
    from .resolve import resolve
    from .train.runs import load_run
    from .solver import linear  # noqa: F401  (register backends)

    settings = build(EvaluateConfig, cfg)
    # a run directory with a config and a checkpoint, before any work
    run, _, _ = load_run(settings.run)
    LINEAR_SOLVERS.get((settings.solver or run.solver).linear)
    return resolve(settings, trained=run)


def evaluate_at(settings, run: Path, fidelity, solver, contact=None, eval_subset=None) -> dict:
    """The run's checkpointed network and geometry evaluated on its task's evaluation set (or
    `eval_subset` samples of it, evenly spaced) at `fidelity` (with `contact` in place of the run's
    own where given)."""
    from .train.runs import fidelity_record, make_trainer

    s = dataclasses.replace(
        settings,
        fidelity=fidelity,
        solver=solver,
        contact=contact or settings.contact,
        logger=dataclasses.replace(settings.logger, name="none"),
        trainer=dataclasses.replace(
            settings.trainer, init_from=str(run), resume="false", eval_subset=eval_subset
        ),
    )
    # the run's own parameters, all of them
    trainer = make_trainer(s, run / "evaluate", exact_init=True)
    t0 = time.perf_counter()
    ev = trainer.final_evaluation(trainer.eval_subset()).record  # from rest
    task = trainer.task
    return {
        "fidelity": fidelity_record(trainer.sim.disc, fidelity),
        "metric": ev[task.metric_name],
        "per_sample": ev["per_sample"],
        "failed_solves": ev["failed_solves"],
        "failed_samples": ev["failed_samples"],
        "over_converged": ev["over_converged"],
        "stopped_inverting": ev["stopped_inverting"],
        **{
            k: ev[k]
            for k in (
                "invalid_states",
                "checked_states",
                "min_J",
                "min_gap",
                "min_boundary_stretch",
                "invalid_samples",
            )
        },
        "seconds": time.perf_counter() - t0,
        "metric_name": task.metric_name,
        "unit": task.metric_unit,
    }


def evaluate(s: EvaluateConfig) -> dict:
    from .train.runs import load_run

    run = Path(s.run)
    settings, _, checkpoint = load_run(run)
    # the run's own where none is chosen: its metric is reproduced
    solver = s.solver or settings.solver
    trained = evaluate_at(settings, run, settings.fidelity, solver, eval_subset=s.eval_subset)
    refined = evaluate_at(settings, run, s.fidelity, solver, s.contact, s.eval_subset)
    a, b = np.asarray(trained["per_sample"]), np.asarray(refined["per_sample"])
    result = {
        "run": str(run),
        "checkpoint": str(checkpoint),
        "task": settings.task.name,
        "metric": trained["metric_name"],
        "unit": trained["unit"],
        "solver": {"from": "run" if s.solver is None else "solver=", **dataclasses.asdict(solver)},
        "samples": len(a),
        "eval_subset": s.eval_subset,
        "training_fidelity": trained,
        "evaluated_fidelity": refined,
        "change": refined["metric"] - trained["metric"],
        "relative_change": (refined["metric"] - trained["metric"]) / abs(trained["metric"])
        if trained["metric"]
        else None,
        "largest_sample_change": float(np.max(np.abs(b - a))) if len(a) == len(b) else None,
    }
    at = refined["fidelity"]
    subset = f"_{len(a)}_samples" if s.eval_subset is not None else ""
    graded = f"_graded{at['grading']:g}" if at["grading"] != 1.0 else ""
    contact = "_contact" if at["contact"] else ""
    out = (
        run
        / "evaluate"
        / f"{at['ctrl_per_patch']}x{at['quad_points']}{graded}{contact}{subset}.json"
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    out = cli.unused_path(out)  # an earlier evaluation at this fidelity stays
    out.write_text(json.dumps(cli.json_safe(result), indent=1, allow_nan=False))
    result["file"] = str(out)
    return result


@hydra.main(config_path=str(CONF_DIR), config_name="evaluate", version_base="1.3")
def hydra_main(cfg: DictConfig) -> None:
    import logging

    with cli.exit_codes(run_dir=Path(hydra.core.hydra_config.HydraConfig.get().runtime.output_dir)):
        result = evaluate(validate(cfg))
    t, e = result["training_fidelity"], result["evaluated_fidelity"]
    logging.getLogger("nma.evaluate").info(
        "%s: %.4g %s at the training fidelity (%d dofs, %d of %d solves failed), %.4g at %dx%d%s "
        "(%d dofs, %d failed); "
        "change %+.3g (each over every sample, a failed solve scored at the worse of the state it "
        "reached and no "
        "actuation)",
        result["metric"],
        t["metric"],
        result["unit"],
        t["fidelity"]["dofs"],
        t["failed_solves"],
        result["samples"],
        e["metric"],
        e["fidelity"]["ctrl_per_patch"],
        e["fidelity"]["quad_points"],
        f" graded {e['fidelity']['grading']:g}" if e["fidelity"]["grading"] != 1.0 else "",
        e["fidelity"]["dofs"],
        e["failed_solves"],
        result["change"],
    )
    brief = {
        k: v for k, v in result.items() if k not in ("training_fidelity", "evaluated_fidelity")
    }
    brief.update(
        training_metric=t["metric"],
        evaluated_metric=e["metric"],
        training_invalid_states=t["invalid_states"],
        evaluated_invalid_states=e["invalid_states"],
        training_failed_solves=t["failed_solves"],
        evaluated_failed_solves=e["failed_solves"],
    )
    for which, record in (("training", t), ("evaluated", e)):
        if record["invalid_states"]:
            from .geometry.validity import describe

            logging.getLogger("nma.evaluate").warning(
                "at the %s fidelity: %s",
                which,
                describe(record, record["invalid_samples"], record["fidelity"]["contact"]),
            )
    print(json.dumps(cli.json_safe(brief), allow_nan=False), flush=True)
    for which, record in (("training", t), ("evaluated", e)):
        # the metric is that of states nobody reached
        if record["failed_solves"] == result["samples"]:
            with cli.exit_codes():
                raise SolverError(
                    f"every solve failed at the {which} fidelity ({record['failed_solves']} of "
                    f"{result['samples']}; {result['file']} says how far each got): the "
                    f"evaluation says nothing of the design"
                )


def main() -> None:
    cli.preflight("evaluate", lambda cfg, hydra_cfg, multirun: validate(cfg), sys.argv[1:])
    hydra_main()


if __name__ == "__main__":
    main()
