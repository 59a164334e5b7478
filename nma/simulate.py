"""One static solve from the command line.

    python -m nma.simulate scene=translation actuation=[1.0,-0.5]

Writes fields.h5 + fields.xdmf and deformation.png into the Hydra run directory and prints one JSON
object on the last line of stdout (scene, dofs, tracked, energy, load_steps, newton_iterations,
converged, seconds).  Exits with status 1 and a clear message if the solve cannot reach full load.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from .config import CONF_DIR


def run(cfg: DictConfig, out_dir: Path) -> dict:
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np

    from .io.fields import write_fields
    from .mechanics.material import material
    from .simulator import Simulator
    from .solver.newton import SolverError
    from .viz.plot import save_reference_and_deformed

    mat = material(cfg.material.E, cfg.material.nu)  # validates before any work
    t0 = time.perf_counter()
    sim = Simulator.from_config(OmegaConf.to_container(cfg.scene), cfg.fidelity, cfg.solver)
    build = time.perf_counter() - t0
    d = jnp.zeros(sim.n_actuations) if cfg.actuation is None else jnp.asarray(list(cfg.actuation), float)
    d = sim.check_actuation(d)
    result = {"scene": sim.disc.spec.name, "dofs": sim.disc.n_dofs, "actuation": np.asarray(d).tolist(),
              "material": {"E": float(cfg.material.E), "nu": float(cfg.material.nu)}}
    try:
        sol = sim.solve(sim.init_params(), d, mat)
    except SolverError as err:
        info = err.info
        return {**result, "converged": False, "error": str(err), "load_reached": float(info.load),
                "load_steps": int(info.load_steps), "newton_iterations": int(info.iterations),
                "residual": float(info.residual)}
    tracked = {k: np.asarray(v).tolist() for k, v in sim.tracked(sol.X, sol.u).items()}
    h5, xdmf = write_fields(out_dir / "fields.h5", sim.disc, sol.X, sol.u, cfg.output.samples,
                            attrs={"actuation": np.asarray(d), "energy": sol.energy})
    result.update({
        "tracked": tracked, "energy": sol.energy, "load_steps": int(sol.info.load_steps),
        "newton_iterations": int(sol.info.iterations), "converged": True,
        "residual": float(sol.info.residual), "tolerance": float(sol.info.tolerance),
        "seconds": sol.seconds, "build_seconds": build, "fields": str(h5), "xdmf": str(xdmf)})
    if cfg.output.figure:
        png = save_reference_and_deformed(out_dir / "deformation.png", sim.disc, sol.X, sol.u,
                                          f"{sim.disc.spec.name}, d = {np.round(np.asarray(d), 3).tolist()}")
        result["figure"] = str(png)
    return result


@hydra.main(config_path=str(CONF_DIR), config_name="simulate", version_base="1.3")
def main(cfg: DictConfig) -> None:
    out_dir = Path(hydra.core.hydra_config.HydraConfig.get().runtime.output_dir)
    try:
        result = run(cfg, out_dir)
    except ValueError as err:  # bad input: say which field, before any work
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    if not result["converged"]:
        print(result["error"], file=sys.stderr)
    print(json.dumps(result), flush=True)
    if not result["converged"]:
        sys.exit(1)


if __name__ == "__main__":
    main()
