"""A hyperelastic law fitted to a material's test data, written as a material file.

    python -m nma.fit data=tensile.csv law=ogden terms=2 output=conf/material/my_silicone.yaml
    python -m nma.fit data="Ecoflex 00-30.csv" strain_column="Engineering Strain" \\
        stress_column="Engineering Stress (MPa)" max_strain=1.5 law=yeoh

The CSV holds the engineering strain and the nominal stress (force over the undeformed section) of
homogeneous incompressible tests: uniaxial tension or compression, and where given equibiaxial and
planar tension (a `mode` column, else `mode=`).  Its header is the first row that names both
columns, so a file with rows of metadata first (the Soft Robotics Materials Database's,
semicolon-separated) reads as it is.

The law's incompressible nominal stress (nma.mechanics.laws.nominal_stress) is fitted by least
squares (scipy.optimize.least_squares, JAX's Jacobian) to the relative residuals (model - data) /
max(|data|, 5% of the largest stress): every part of the curve counts, the small strains included,
and a point near zero stress does not dominate.  Several initial guesses are tried (`starts`).  The
fitted law must be stable (Drucker) over the data's stretches.  Each law gives its fit's first
guess and bounds (Law.fit_start: Gent's Jm, say, is bounded where Gent is Neo-Hookean's) and what
to note of the result (Law.fit_notes).

The material file holds the parameters, nu (with the volume term `lame`: nu is the 3D Poisson's
ratio, material.volumetric), the unit, those stretches, the source, and the fit's
record (data file and its sha256, columns, points, range, errors); one JSON line with the same goes
to stdout.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import logging
import sys
from pathlib import Path

import hydra
import numpy as np
from omegaconf import DictConfig

from . import cli
from .config import CONF_DIR
from .errors import ConfigError
from .mechanics.options import MODES
from .schema import build, register
from .schema.commands import FitConfig

log = logging.getLogger("nma.fit")
register()
FLOOR = 0.05  # the residuals' denominator is at least this fraction of the largest measured stress


DELIMITERS = ",;\t"


def _header(text: str, strain_column: str, stress_column: str):
    """(rows, index of the header, delimiter): the first row that, split by one of DELIMITERS, names
    both columns; None where none does."""
    found, wanted = None, {strain_column, stress_column}
    for delimiter in DELIMITERS:
        rows = list(csv.reader(io.StringIO(text), delimiter=delimiter))
        head = next((i for i, r in enumerate(rows) if wanted <= {c.strip() for c in r}), None)
        if head is not None and (found is None or head < found[1]):
            found = (rows, head, delimiter)
    return found


def _number(cell: str, delimiter: str) -> float:
    """A cell's number; a decimal comma is one where commas do not separate the cells."""
    cell = cell.strip()
    return float(cell.replace(",", ".") if delimiter != "," else cell)


def read(path, strain_column: str, stress_column: str, mode: str, max_strain: float | None):
    """(modes, stretches, stresses) from a CSV: the rows after the first that names both columns
    (split by a comma, semicolon or tab), each with numbers in both; `mode` where the file has no
    `mode` column.  The data's problems (a number not finite, a strain at or below -1, too few
    points, a stress of the other sign, a constant stress, a stress that falls as the strain grows)
    are refused, each in one line."""
    if mode not in MODES:
        raise ConfigError(f"mode must be one of {list(MODES)}, got {mode!r}")
    if max_strain is not None and not float(max_strain) > 0:
        raise ConfigError(f"max_strain must be a positive number or null, got {max_strain!r}")
    text = Path(path).read_text(encoding="utf-8-sig", errors="replace")
    found = _header(text, strain_column, stress_column)
    if found is None:
        raise ConfigError(
            f"data={path}: no row names both columns strain_column={strain_column!r} "
            f"and stress_column={stress_column!r} (cells split by a comma, semicolon or tab)"
        )
    rows, head, delimiter = found
    names = [c.strip() for c in rows[head]]
    e, s = names.index(strain_column), names.index(stress_column)
    m = names.index("mode") if "mode" in names else None
    modes, strains, stresses = [], [], []
    for line, r in enumerate(rows[head + 1 :], start=head + 2):
        try:
            strain, stress = _number(r[e], delimiter), _number(r[s], delimiter)
        except (ValueError, IndexError):
            continue
        for column, cell in ((strain_column, r[e]), (stress_column, r[s])):
            if not np.isfinite(_number(cell, delimiter)):
                raise ConfigError(
                    f"data={path}: row {line} has {column} {cell.strip()!r}: every "
                    "number must be finite (mend or delete the row)"
                )
        if strain <= -1.0:
            raise ConfigError(
                f"data={path}: row {line} has {strain_column} {strain:g}: an "
                "engineering strain must exceed -1 (a stretch above 0)"
            )
        if strain == 0.0 or (max_strain is not None and abs(strain) > max_strain):
            continue
        modes.append(r[m].strip() if m is not None else mode)
        strains.append(strain)
        stresses.append(stress)
    unknown = sorted(set(modes) - set(MODES))
    if unknown:
        raise ConfigError(
            f"data={path}: column mode holds {unknown}; each row's must be uniaxial, "
            "biaxial or planar"
        )
    upto = f" up to max_strain={max_strain:g}" if max_strain is not None else ""
    if len(strains) < 3:
        raise ConfigError(
            f"data={path}: {len(strains)} rows with numbers in both columns{upto}; a "
            "fit needs at least 3"
        )
    return _curve(
        path, stress_column, upto, np.asarray(modes), np.asarray(strains), np.asarray(stresses)
    )


def _curve(path, stress_column, upto, modes, strains, stresses):
    """(modes, stretches, stresses) of the rows a law can follow: a row whose stress is of the other
    sign than its strain but within FLOOR of the largest stress (a test's offset about zero at its
    start) is left out.  Refuses, naming the problem, fewer than 3 distinct points, a significant
    stress of the other sign, a constant stress, a test whose stress does not grow with its
    strain."""
    against = strains * stresses < 0  # a stretched specimen pulls back, a compressed one pushes
    if np.any(against):
        if np.any(against & (np.abs(stresses) > FLOOR * np.max(np.abs(stresses)))):
            raise ConfigError(
                f"data={path}: {int(np.sum(against))} of {len(strains)} rows have a "
                "stress of the other sign than their strain; check "
                f"stress_column={stress_column!r} (tension is positive in both)"
            )
        modes, strains, stresses = modes[~against], strains[~against], stresses[~against]
    distinct = len(set(zip(modes.tolist(), strains.tolist())))
    if distinct < 3:
        raise ConfigError(
            f"data={path}: {len(strains)} rows at {distinct} distinct "
            f"strain{'s' * (distinct != 1)}{upto}; a fit needs the stress at at least 3"
        )
    if np.ptp(stresses) == 0:
        raise ConfigError(
            f"data={path}: the stress is {stresses[0]:g} at every strain; a law's "
            f"stress grows with its strain: check stress_column={stress_column!r}"
        )
    for mode in np.unique(modes):
        e, s = strains[modes == mode], stresses[modes == mode]
        if np.ptp(e) == 0:
            continue
        rank_e, rank_s = np.argsort(np.argsort(e)), np.argsort(np.argsort(s))
        if np.ptp(s) == 0 or np.corrcoef(rank_e, rank_s)[0, 1] <= 0:
            lo, hi = np.argmin(e), np.argmax(e)
            raise ConfigError(
                f"data={path}: in the {mode} test the stress does not grow with the "
                f"strain (it is {s[lo]:g} at strain {e[lo]:g} and {s[hi]:g} at "
                f"strain {e[hi]:g}); check strain_column and stress_column"
            )
    return modes, 1.0 + strains, stresses


def _model(law, modes, stretches):
    """The nominal stresses of `law` at the data's modes and stretches, a function of its
    parameters."""
    import jax.numpy as jnp

    from .mechanics.laws import nominal_stress

    groups = [(mode, np.flatnonzero(modes == mode)) for mode in np.unique(modes)]
    order = np.concatenate([idx for _, idx in groups])
    back = np.argsort(order)

    def stresses(p):
        return jnp.concatenate(
            [nominal_stress(law, p, mode, stretches[idx]) for mode, idx in groups]
        )[back]

    return stresses


def _initial_shear(stretches, stresses):
    """mu0 from the small-strain slope: nominal stress ~ 3 mu0 (lambda - 1) in uniaxial tension."""
    small = np.argsort(np.abs(stretches - 1.0))[: max(3, len(stretches) // 10)]
    slope = np.sum(stresses[small] * (stretches[small] - 1.0)) / np.sum(
        (stretches[small] - 1.0) ** 2
    )
    return max(abs(slope) / 3.0, 1e-12)


def _guesses(law, mu0: float, stretches, starts: int, i1_max: float, seed: int = 0):
    """Initial parameters and bounds: the law's first guess at the data's initial shear modulus mu0
    (Law.fit_start), then random ones (each parameter scaled by a factor in [0.3, 3], and as the
    law draws them: Law.fit_draw), inside the bounds."""
    rng = np.random.default_rng(seed)
    first, lo, hi = (np.asarray(v, float) for v in law.fit_start(mu0, stretches, i1_max))
    guesses = [first]
    for _ in range(starts - 1):
        g = law.fit_draw(first * rng.uniform(0.3, 3.0, len(first)), mu0, rng)
        guesses.append(np.clip(g, lo + 1e-12, hi - 1e-12))
    return guesses, (lo, hi)


def fit(cfg: FitConfig) -> dict:
    """The fitted law, its errors and the material file's contents (written where cfg.output
    says)."""
    from .runtime import configure_jax

    configure_jax()
    import jax
    import jax.numpy as jnp
    from scipy.optimize import least_squares

    from .mechanics.laws import drucker_unstable, law_of, mode_stretches

    law = law_of(cfg.law, [f"mu{k}" for k in range(1, cfg.terms + 1)] if cfg.law == "ogden" else ())
    modes, stretches, data = read(
        cfg.data, cfg.strain_column, cfg.stress_column, cfg.mode, cfg.max_strain
    )
    what = f"law={cfg.law}" + (f" terms={cfg.terms}" if cfg.law == "ogden" else "")
    distinct = len(set(zip(modes.tolist(), stretches.tolist())))
    if distinct < len(law.names):
        raise ConfigError(
            f"data={cfg.data}: {distinct} distinct points; {what} has "
            f"{len(law.names)} parameters {list(law.names)}, which need at least as many"
        )
    i1_max = max(
        float(np.max(np.sum(np.asarray(mode_stretches(m, stretches[modes == m])) ** 2, axis=0)))
        for m in np.unique(modes)
    )  # the data's largest I1
    scale = np.maximum(np.abs(data), FLOOR * np.max(np.abs(data)))
    model = _model(law, modes, stretches)
    residual = jax.jit(lambda p: (model(p) - data) / scale)
    jacobian = jax.jit(jax.jacfwd(lambda p: (model(p) - data) / scale))
    # the stretches the data reach: uniaxial tension to l_max compresses the sides to l_max^-1/2,
    # and no mode is checked past a principal stretch the data did not reach (biaxial at
    # l_max^-1/2 stretches its third to l_max)
    top = max(float(np.max(stretches)), 1.01)
    stretch_range = [min(float(np.min(stretches)), top**-0.5, 0.99), top]
    guesses, bounds = _guesses(law, _initial_shear(stretches, data), stretches, cfg.starts, i1_max)
    best, unstable = None, None  # the best stable fit; the best fit refused as unstable, and why
    for guess in guesses:
        with np.errstate(all="ignore"):
            try:
                r = least_squares(
                    lambda p: np.asarray(residual(jnp.asarray(p))),
                    guess,
                    bounds=bounds,
                    jac=lambda p: np.asarray(jacobian(jnp.asarray(p))),
                    x_scale="jac",
                    max_nfev=2000,
                )
            except ValueError:  # a guess where the law is not finite
                continue
        values = dict(zip(law.names, r.x.tolist()))
        if (
            not np.all(np.isfinite(r.fun))
            or law.out_of_range(values)
            or not float(law.shear_modulus({**values, "nu": cfg.nu})) > 0
            or (best is not None and r.cost >= best.cost)
        ):
            continue  # not a law (an Ogden exponent at 0 is a term of no stress), or no better
        why = drucker_unstable(law, jnp.asarray(r.x), tuple(stretch_range))
        if not why:
            best = r
        elif unstable is None or r.cost < unstable[0].cost:
            unstable = (r, why)
    if best is None:
        found = (
            ""
            if unstable is None
            else (
                f"; the best, {dict(zip(law.names, unstable[0].x.round(6).tolist()))}, is "
                f"not stable (Drucker) over the data's stretches "
                f"{[round(x, 3) for x in stretch_range]}: {unstable[1]}"
            )
        )
        raise ConfigError(
            f"law={law.name}: no fit from {cfg.starts} starts is stable with finite stresses at "
            f"every data point{found}; try another law (Ogden with more terms), or more starts"
        )
    p = best.x
    notes = law.fit_notes(dict(zip(law.names, p.tolist())), bounds[1].tolist(), cfg.nu)
    fitted = np.asarray(model(jnp.asarray(p)))
    rel = (fitted - data) / scale
    record = {
        "data": Path(cfg.data).name,
        "sha256": hashlib.sha256(Path(cfg.data).read_bytes()).hexdigest(),
        "modes": sorted(set(modes.tolist())),
        "columns": [cfg.strain_column, cfg.stress_column],
        "points": int(len(data)),
        "strain_range": [float(np.min(stretches) - 1.0), float(np.max(stretches) - 1.0)],
        "rms_relative_error": float(np.sqrt(np.mean(rel**2))),
        "max_relative_error": float(np.max(np.abs(rel))),
        "r2": float(1.0 - np.sum((fitted - data) ** 2) / np.sum((data - np.mean(data)) ** 2)),
    }
    material = {
        "name": cfg.name,
        "law": cfg.law,
        "E": None,
        "nu": cfg.nu,
        # nu the 3D Poisson's ratio of a shipped or fitted elastomer (material.volumetric)
        "volumetric": "lame" if law.volume_term else "auto",
        "parameters": {n: float(v) for n, v in zip(law.names, p)},
        "unit": cfg.unit,
        "stretches": [round(stretch_range[0], 4), round(stretch_range[1], 4)],
        "source": cfg.source,
        "fit": record,
    }
    if notes:
        record["note"] = " ".join(notes)
    from .schema import MaterialConfig

    try:
        MaterialConfig(**material)  # it must load as a material: ranges, shear modulus, stability
    except ConfigError as err:
        raise ConfigError(
            f"{what}: the fit {material['parameters']} is not a material a solve can take: {err}"
        ) from None
    for note in notes:
        log.warning("%s", note)
    if cfg.output:
        write(Path(cfg.output), material)
    return {"material": material, "output": cfg.output}


def write(path: Path, material: dict) -> Path:
    import yaml

    what = material["name"] or Path(material["fit"]["data"]).stem
    article = "an" if material["law"][0] in "aeiou" else "a"
    header = (
        f"# {what}: {article} {material['law']} law fitted to "
        f"{', '.join(material['fit']['modes'])} test data by nma.fit\n"
        "# (the fit's record below). Fields and ranges: nma/schema/physics.py (MaterialConfig).\n"
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(header + yaml.safe_dump(material, sort_keys=False, width=110))
    return path


def validate(cfg: DictConfig) -> FitConfig:
    return build(FitConfig, cfg)


@hydra.main(config_path=str(CONF_DIR), config_name="fit", version_base="1.3")
def hydra_main(cfg: DictConfig) -> None:
    with cli.exit_codes():
        result = fit(validate(cfg))
    r = result["material"]["fit"]
    log.info(
        "%s: rms relative error %.3g, largest %.3g, R^2 %.5f over %d points%s",
        result["material"]["law"],
        r["rms_relative_error"],
        r["max_relative_error"],
        r["r2"],
        r["points"],
        f"; written to {result['output']}" if result["output"] else "",
    )
    print(json.dumps(cli.json_safe(result), allow_nan=False), flush=True)


def main() -> None:
    cli.preflight("fit", lambda cfg, hydra_cfg, multirun: validate(cfg), sys.argv[1:])
    hydra_main()


if __name__ == "__main__":
    main()
