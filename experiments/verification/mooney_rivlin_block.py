"""A block of a nearly incompressible Mooney-Rivlin solid in plane-strain compression against the
incompressible closed form (tests/test_mooney_rivlin_block.py).

Incompressible plane strain with a free lateral face: F = diag(1/l, l, 1), W = (C10 + C01)(l^2 +
l^-2 - 2), so the nominal stress along the load is P = dW/dl = 2 (l - l^-3)(C10 + C01) and the
lateral stretch is 1/l (e.g. Ogden, Non-linear Elastic Deformations, sec. 7.2; Holzapfel,
Nonlinear Solid Mechanics, sec. 6.5).  The block, 1 x 1 in 2 x 2 solid cells, slides on its left
and bottom edges (the normal component held, the tangential free) and carries a dead compressive
traction on its top, so its deformation is homogeneous; the `mixed` formulation (each element's
mean dilatation) at nu = 0.499 and 0.4999.  A homogeneous field is in the spline space and its mean
dilatation is its own, so the model solves the compressible law's homogeneous state exactly (held
to 1e-8 against that state, found here from nma's law at F = diag(a, l) with P_11 = 0).  What stays
between it and the incompressible closed form is the volume change: the mean stress p, of the order
of mu0 + |P|, changes the volume by about p / kappa (kappa the volume term's bulk modulus), and the
stress at a given l by a relative amount of the same order; the tolerance is twice (mu0 + |P|) /
kappa, in the stress and in the volume (found: 0.4 to 0.46 of it, 0.3% to 0.8% at nu = 0.499, ten
times less at nu = 0.4999).
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
from scipy.optimize import brentq

C10, C01 = 0.3, 0.05  # MPa; mu0 = 2 (C10 + C01) = 0.7
STRETCHES = (0.9, 0.8, 0.7, 0.6)  # the incompressible closed form's stretches the loads are set at
NUS = (0.499, 0.4999)
CTRL = 5  # control points per patch: a homogeneous field is exact on any mesh
EXACT_TOLERANCE = 1e-8  # relative, against the compressible homogeneous state: the solver's
COMPRESSIBILITY_FACTOR = 2.0  # the closed form: within this multiple of (mu0 + |P|) / kappa


def closed_form_stress(lam):
    """P = 2 (l - l^-3)(C10 + C01): incompressible plane-strain nominal stress along the load."""
    lam = np.asarray(lam, float)
    return 2.0 * (lam - lam**-3) * (C10 + C01)


def block_spec(traction: float):
    """The block's scene: sliding on x = 0 and y = 0, the dead load (0, -traction) per unit length
    on its top, its top right corner tracked."""
    from nma.geometry.scene import SceneSpec, Traction
    from nma.schema.scene import SceneConfig, SupportConfig

    @dataclasses.dataclass(frozen=True)
    class LoadedBlock(SceneSpec):  # a cell grid with a dead traction (Cook's membrane's kind)
        tractions: tuple = ()

    base = SceneConfig(
        name="mooney_rivlin_block",
        cells="SS\nSS",
        cell_size=0.5,
        supports=[
            SupportConfig(segment=[[0.0, 0.0], [0.0, 1.0]], kind="sliding"),
            SupportConfig(segment=[[0.0, 0.0], [1.0, 0.0]], kind="sliding"),
        ],
        tracked={"corner": [1.0, 1.0], "centre": [0.5, 0.5]},
    ).spec()
    fields = {f.name: getattr(base, f.name) for f in dataclasses.fields(base)}
    return LoadedBlock(**fields, tractions=(Traction(((0.0, 1.0), (1.0, 1.0)), (0.0, -traction)),))


def homogeneous_state(material, params, lam: float) -> tuple[float, float]:
    """(lateral stretch a, P_22) of nma's law at F = diag(a, lam) with P_11 = 0."""
    import jax.numpy as jnp

    P = material.point_terms(jnp.asarray(params))[1]
    p11 = lambda a: float(P(jnp.diag(jnp.array([a, lam])))[0, 0])
    a = brentq(p11, 0.5 / lam, 2.0 / lam, xtol=1e-15, rtol=1e-15)
    return a, float(P(jnp.diag(jnp.array([a, lam])))[1, 1])


def compress(nu: float, stretches=STRETCHES, ctrl: int = CTRL) -> list[dict]:
    """The block under the tractions of the closed form at `stretches`: per load, the stretches
    (along and across the load) the model reaches, the compressible state's and the closed
    form's."""
    import jax.numpy as jnp

    from nma.discretise import Resolution, discretise
    from nma.mechanics.laws import law_of
    from nma.mechanics.material import Material
    from nma.simulator import Simulator

    material = Material("mixed", law_of("mooney_rivlin"), "bulk")  # volume term kappa/2 (log J)^2
    params = jnp.array([C10, C01, nu])
    mu, kappa = (float(m) for m in material.moduli(params))
    out = []
    for target in stretches:
        traction = -float(closed_form_stress(target))
        sim = Simulator(discretise(block_spec(traction), Resolution(ctrl, 3), material=material))
        X = sim.reference_points(sim.init_params())
        eq = sim.solve(sim.init_params(), jnp.zeros(0), params)
        tracked = sim.tracked(X, eq.u)
        corner = np.asarray(tracked["corner"])
        centre = np.asarray(tracked["centre"])
        lam, lateral = float(corner[1]), float(corner[0])  # the block is 1 x 1
        exact_lateral, exact_stress = homogeneous_state(material, params, lam)
        out.append(
            {
                "target": target,
                "traction": traction,
                "converged": bool(eq.converged),
                "stretch": lam,
                "lateral": lateral,
                "homogeneous": float(np.max(np.abs(centre - 0.5 * corner))),
                "exact_lateral": exact_lateral,
                "exact_error": max(
                    abs(lateral / exact_lateral - 1.0), abs(exact_stress / -traction - 1.0)
                ),
                "closed_form_stress": float(closed_form_stress(lam)),
                "stress_error": float(closed_form_stress(lam) / -traction - 1.0),
                "lateral_error": lateral * lam - 1.0,
                "tolerance": COMPRESSIBILITY_FACTOR * (mu + abs(traction)) / kappa,
                "mu_over_kappa": mu / kappa,
            }
        )
    return out


def run() -> dict:
    out, failures = {}, []
    for nu in NUS:
        t0 = time.perf_counter()
        loads = compress(nu)
        for ld in loads:
            where = f"Mooney-Rivlin block at nu {nu}, stretch {ld['target']}"
            if not ld["converged"]:
                failures.append(f"{where}: the solve did not converge")
            if ld["exact_error"] > EXACT_TOLERANCE or ld["homogeneous"] > EXACT_TOLERANCE:
                failures.append(
                    f"{where}: {ld['exact_error']:.2g} from the homogeneous state (centre off by "
                    f"{ld['homogeneous']:.2g}), over {EXACT_TOLERANCE:g}"
                )
            worst = max(abs(ld["stress_error"]), abs(ld["lateral_error"]))
            if worst > ld["tolerance"]:
                failures.append(
                    f"{where}: {worst:.2g} from the incompressible closed form, over "
                    f"{ld['tolerance']:.2g}"
                )
        out[str(nu)] = {
            "nu": nu,
            "loads": loads,
            "seconds": time.perf_counter() - t0,
        }
    return {
        "C10": C10,
        "C01": C01,
        "ctrl_per_patch": CTRL,
        **out,
        "exact_tolerance": EXACT_TOLERANCE,
        "failures": failures,
    }


def section(r: dict) -> list[str]:
    lines = [
        "## Mooney-Rivlin block, plane-strain compression",
        "",
        f"A 1 x 1 block of Mooney-Rivlin solid (C10 = {r['C10']:g}, C01 = {r['C01']:g} MPa), "
        "sliding on its left and bottom edges, under a dead compressive traction on its top: a "
        "homogeneous deformation, against the incompressible closed form P = 2 (l - l^-3)(C10 + "
        "C01) with the lateral stretch 1/l (Ogden, Non-linear Elastic Deformations, sec. 7.2). "
        "The traction is the closed form's at the stretch l0; l is the stretch the model reaches. "
        f"The mixed formulation, 2 x 2 cells, {r['ctrl_per_patch']} control points per patch: one "
        "level, the deformation being homogeneous (the model matches the compressible law's "
        f"homogeneous state within {r['exact_tolerance']:g}). Tolerance against the closed form: "
        "the remaining compressibility, 2 (mu0 + |P|) / kappa in the nominal stress at l and in "
        "the volume l x lateral - 1 (mu0 = 2 (C10 + C01), kappa the volume term's bulk modulus).",
        "",
        "| nu | mu0/kappa | l0 | applied P | l | lateral (1/l) | closed form P(l) | relative "
        "error | volume - 1 | tolerance |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for key in (k for k in r if isinstance(r[k], dict) and "loads" in r[k]):
        c = r[key]
        for ld in c["loads"]:
            lines.append(
                f"| {c['nu']:g} | {ld['mu_over_kappa']:.1e} | {ld['target']:g} | "
                f"{-ld['traction']:.6g} | {ld['stretch']:.6f} | {ld['lateral']:.6f} "
                f"({1 / ld['stretch']:.6f}) | {ld['closed_form_stress']:.6g} | "
                f"{ld['stress_error']:+.1e} | {ld['lateral_error']:+.1e} | {ld['tolerance']:.1e} |"
            )
    return lines
