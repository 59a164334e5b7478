"""One static solve from the command line, or with dynamics the actuation applied over time.

    python -m nma.simulate scene=translation actuation=[1.0,-0.5] [dynamics=newmark]
    python -m nma.simulate scene=square_array load=uniaxial_y load.strain=-0.2

Writes fields.h5 + fields.xdmf and deformation.png into the Hydra run directory and prints one JSON
object on the last line of stdout (scene, dofs, tracked, energy, load_steps, newton_iterations,
converged, valid, validity, seconds, natural_frequencies: about the equilibrium, or with dynamics
at rest, whichever dynamics.start; with dynamics, `dynamics`: nma.dynamics.report; `plane_strain`:
the material's volume term and the plane modulus and in-plane Poisson's ratio it gives at small
strain, beside the 3D-consistent E / (1 - nu^2) and nu / (1 - nu): nma.mechanics.material);
a value that is not finite is written as null, so the line is
always JSON.  `valid` says whether the equilibrium is a physical object (nma/geometry/validity.py:
det F over the whole material, no boundary curve through itself or another); `validity` has the
details. With dynamics, `converged` and `valid` are the run in time's too: every time step
converged, and every state of the trajectory (each checked) is a physical object.
A periodic scene (scene.periodic) follows its macroscopic load instead (load=uniaxial_y etc.,
conf/load/; nma.periodic.command): the JSON line lists every state's strains, average nominal
stress, Poisson's ratio and validity, and the critical strain of a bifurcation crossed; fields.h5
holds the last state, mode.h5 the bifurcation's mode, path.png the tiled cell and its curves.
Exit codes as in nma.cli: 2 for bad input (before any work), 1 if the solve cannot reach full
load or a time step fails (one line on stderr says when and why; the JSON line says how far it got).
"""

from __future__ import annotations

import json
import logging
import sys
import time
from pathlib import Path

import hydra
from omegaconf import DictConfig

from . import cli
from .cli import json_safe
from .config import CONF_DIR
from .errors import ConfigError, SolverError
from .resolve import material_params, model_record, resolve
from .schema import SimulateConfig, build, register

log = logging.getLogger("nma.simulate")
register()


def validate(cfg: DictConfig) -> SimulateConfig:
    from .registry import LINEAR_SOLVERS
    from .solver import linear  # noqa: F401  (register backends)

    settings = build(SimulateConfig, cfg)
    LINEAR_SOLVERS.get(settings.solver.linear)
    return resolve(settings)


def run(s: SimulateConfig, out_dir: Path) -> dict:
    from .runtime import configure_jax

    configure_jax()
    if s.scene.periodic:  # a load path of F_bar, not an actuation
        from .periodic.command import run as follow_path

        return follow_path(s, out_dir)
    import jax.numpy as jnp
    import numpy as np

    from .schema import scene_from_config
    from .geometry.validity import StateChecker
    from .io.fields import write_fields
    from .mechanics.material import plane_strain_record
    from .simulator import Simulator
    from .units import Units
    from .viz.plot import save_reference_and_deformed

    spec = scene_from_config(s.scene)
    mat = material_params(s.material)
    units = Units.of(s.part, s.material)
    t0 = time.perf_counter()
    sim = Simulator.from_settings(s)
    build_seconds = time.perf_counter() - t0
    d = sim.check_actuation(
        jnp.zeros(sim.n_actuations) if s.actuation is None else jnp.asarray(s.actuation)
    )
    result = {
        "scene": spec.name,
        "dofs": sim.disc.boundary.n_dofs,
        "contact": s.contact.enabled,
        "actuation": np.asarray(d).tolist(),
        "material": s.material.record(),
        "plane_strain": plane_strain_record(sim.disc.material, mat),
        "model": model_record(s),
        "units": units.record(),
    }
    plane = result["plane_strain"]
    log.info(
        "material.volumetric=%s: at small strain, under uniaxial plane-strain stress, the plane "
        "modulus is %.4g (%.4f x E / (1 - nu^2)) and the in-plane Poisson's ratio %.4f "
        "(nu / (1 - nu) = %.4f)",
        plane["volumetric"] or "none (the law's energy is whole)",
        plane["modulus"],
        plane["modulus"] / plane["modulus_3d_consistent"],
        plane["poisson"],
        plane["poisson_3d_consistent"],
    )
    params = sim.init_params()
    t0 = time.perf_counter()
    eq = sim.solve(params, d, mat, throw=False)
    seconds = time.perf_counter() - t0
    info = eq.info
    if not eq.converged:
        return {
            **result,
            "converged": False,
            "error": str(sim.failure(eq, d, mat)),
            "load_reached": float(info.load),
            "load_steps": int(info.load_steps),
            "newton_iterations": int(info.iterations),
            "residual": float(info.residual),
        }
    X = np.asarray(sim.reference_points(params))
    energy = sim.energy(X, eq.u, mat)
    tracked = {k: np.asarray(v).tolist() for k, v in sim.tracked(X, eq.u).items()}
    checker = StateChecker(sim.disc.mesh, X)
    state = checker.check(eq.u)
    if not state.valid:
        log.warning("the equilibrium is not a physical object: %s", "; ".join(state.problems()))
    h5, xdmf = write_fields(
        out_dir / "fields.h5",
        sim.disc,
        X,
        eq.u,
        s.output.samples,
        attrs={"actuation": np.asarray(d), "energy": energy},
    )
    forces = np.asarray(sim.actuation_forces(X, eq.u, mat)).tolist()
    result.update(
        {
            "tracked": tracked,
            **(
                {"tracked_mm": {k: units.convert(v, "length") for k, v in tracked.items()}}
                if units.mm_per_unit is not None
                else {}
            ),
            "actuation_forces": forces,
            **units.physical("actuation_forces", forces, "force"),
            "energy": energy,
            "load_steps": int(info.load_steps),
            "newton_iterations": int(info.iterations),
            "converged": True,
            "valid": state.valid,
            "validity": {**state.record(), "resolution": checker.resolution},
            "residual": float(info.residual),
            "tolerance": float(info.tolerance),
            "seconds": seconds,
            "build_seconds": build_seconds,
            "fields": str(h5),
            "xdmf": str(xdmf),
        }
    )
    from .dynamics import report

    # one modal solve: about this equilibrium; in time at rest (its time step, either start)
    about = () if s.dynamics.enabled else (d, eq.u)
    modes = report.frequencies(sim, X, mat, s.material.density, *about)
    result.update(modes)
    if s.dynamics.enabled:
        where = f"scene {spec.name}, actuation {np.asarray(d).tolist()}"
        try:
            result.update(report.over_time(s, sim, X, d, mat, eq.u, out_dir, modes))
        except SolverError as err:  # nothing moved: the static result stands, the run in time not
            result.update(converged=False, valid=False, error=f"{where}: {err}")
        else:
            dyn = result["dynamics"]
            # the run's verdict is the run in time's: every state reached, every one physical
            result["valid"] = state.valid and dyn["every_state_physical"]
            if not dyn["completed"]:
                result.update(converged=False, error=f"{where}: {dyn['why']}")
    if s.output.figure:
        png = save_reference_and_deformed(
            out_dir / "deformation.png",
            sim.disc,
            X,
            eq.u,
            f"{spec.name}, d = {np.round(np.asarray(d), 3).tolist()}",
        )
        result["figure"] = str(png)
    return result


@hydra.main(config_path=str(CONF_DIR), config_name="simulate", version_base="1.3")
def hydra_main(cfg: DictConfig) -> None:
    out_dir = Path(hydra.core.hydra_config.HydraConfig.get().runtime.output_dir)
    with cli.exit_codes(run_dir=out_dir):
        result = run(validate(cfg), out_dir)
    if not result["converged"]:
        print(f"error: {result['error']}", file=sys.stderr)
    print(json.dumps(json_safe(result), allow_nan=False), flush=True)
    if not result["converged"]:
        sys.exit(cli.FAILED)


def main() -> None:
    def check(cfg, hydra_cfg, multirun):
        validate(cfg)
        out = cli.job_dir(hydra_cfg, multirun)
        # a run's, or an earlier solve's
        if out.is_dir() and any(p.name != cli.RUN_LOCK for p in out.iterdir()):
            raise ConfigError(
                f"hydra.run.dir={out} holds files already: nma.simulate writes a directory of its "
                f"own (without hydra.run.dir each solve gets a new one)"
            )

    cli.preflight("simulate", check, sys.argv[1:])
    hydra_main()


if __name__ == "__main__":
    main()
