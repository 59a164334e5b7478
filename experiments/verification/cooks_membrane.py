"""Cook's membrane, plane strain, nearly incompressible Neo-Hookean (de Souza Neto et al. 1996; the
problem of OpenGeoSys's F-bar benchmark and of Elguedj et al. 2008): the tip's vertical displacement
against 6.93 +- 0.015 mm, displacement and mixed formulations under refinement
(tests/test_cooks_membrane.py)."""

from __future__ import annotations

import time

import numpy as np

from .common import order, relative_error, richardson_or_none


REFERENCE_TIP, REFERENCE_TIP_SPREAD = 6.93, 0.015
COOK_LAME = {"mu": 80.194, "kappa": 400889.8}
COOK_SPANS = (24, 36, 48)  # spans per side; control points = spans + 2
# the Richardson limit of the three tips against the reference, relative (the tests' tolerances)
COOK_TOLERANCE = {"displacement": 0.01, "mixed": 0.005}

# OpenGeoSys's published sequence of the same problem (ufz/ogs, Tests/Data/LargeDeformation/
# CooksMembrane/CooksMembraneFbar.py at 4430b6b, expected_uys_at_top_fbar and _non_fbar, m -> mm):
# 4-node quadrilaterals with F-bar and without, n elements per side.  Its energy, K/2 (J - 1)^2 +
# G/2 (tr(J^(-2/3) C) - 3), and nma's Neo-Hookean with log J are the same solid to O(G/K) = 2e-4.
OGS_URL = (
    "https://github.com/ufz/ogs/blob/4430b6b85cccccba693df06c5f31dcec5456d4ac/"
    "Tests/Data/LargeDeformation/CooksMembrane/CooksMembraneFbar.py"
)
OGS_ELEMENTS = (4, 10, 15, 20, 25, 30)
OGS_FBAR = (6.141383, 6.746284, 6.824183, 6.858936, 6.873126, 6.891409)
OGS_STANDARD = (2.286722, 2.840692, 3.374581, 3.881200, 4.242929, 4.702757)
# nma's mixed tips against OGS F-bar's finest, which approaches from below (still under the
# reference at 30 elements) where nma's mixed approaches from above: within 1%, and bracketing it
OGS_TOLERANCE = 0.01


def tip_displacement(ctrl: int, formulation: str = "displacement") -> float:
    """The tip's vertical displacement (mm) at `ctrl` control points per side."""
    import jax.numpy as jnp

    from nma.discretise import Resolution, discretise
    from nma.geometry.scene import cooks_membrane
    from nma.mechanics.material import from_lame
    from nma.simulator import Simulator

    sim = Simulator(discretise(cooks_membrane(), Resolution(ctrl, 3), material=formulation), "auto")
    sol = sim.solve({}, jnp.zeros(0), from_lame(**COOK_LAME))
    return float(sim.tracked(sim.reference_points({}), sol.u)["tip"][1] - 60.0)


def run() -> dict:
    out, failures = {}, []
    for formulation in ("displacement", "mixed"):
        levels = []
        for spans in COOK_SPANS:
            t0 = time.perf_counter()
            tip = tip_displacement(spans + 2, formulation)
            levels.append({"spans": spans, "tip": tip, "seconds": time.perf_counter() - t0})
        tips = [lv["tip"] for lv in levels]
        limit, rate = richardson_or_none(COOK_SPANS, tips)
        tolerance = COOK_TOLERANCE[formulation]
        side = 1.0 if formulation == "displacement" else -1.0  # locking: from below; mixed: above
        if not np.all(side * np.diff(tips) > 0):
            failures.append(f"Cook's membrane, {formulation}: the tips are not monotone {tips}")
        if limit is None or abs(limit / REFERENCE_TIP - 1.0) > tolerance:
            failures.append(
                f"Cook's membrane, {formulation}: the extrapolated tip {limit} is more than "
                f"{tolerance * 100:g}% from {REFERENCE_TIP}"
            )
        if formulation == "mixed" and not all(
            OGS_FBAR[-1] < tip < (1.0 + OGS_TOLERANCE) * OGS_FBAR[-1] for tip in tips
        ):
            failures.append(
                f"Cook's membrane, mixed: the tips {tips} are not within {OGS_TOLERANCE:.0%} above "
                f"OpenGeoSys's F-bar tip at {OGS_ELEMENTS[-1]} elements, {OGS_FBAR[-1]}"
            )
        out[formulation] = {
            "levels": levels,
            "limit": limit,
            "observed_order": rate,
            "tolerance": tolerance,
        }
    return {
        "reference": REFERENCE_TIP,
        "reference_spread": REFERENCE_TIP_SPREAD,
        "opengeosys": {
            "source": OGS_URL,
            "elements_per_side": OGS_ELEMENTS,
            "f_bar": OGS_FBAR,
            "standard": OGS_STANDARD,
        },
        **out,
        "failures": failures,
    }


def section(cook: dict) -> list[str]:
    lines = [
        "## Cook's membrane",
        "",
        "Plane strain, nearly incompressible Neo-Hookean (mu = 80.194, kappa = 400889.8 MPa; de "
        "Souza Neto et al. 1996; the same problem as OpenGeoSys's F-bar benchmark, "
        "https://www.opengeosys.org/docs/benchmarks/large-deformations/cooksmembranefbar, after "
        "Elguedj et al. 2008), 100 N of shear (6.25 N/mm) on the right edge: the tip's vertical "
        "displacement. "
        f"Reference {REFERENCE_TIP} +- {REFERENCE_TIP_SPREAD} mm, measured for this project with "
        "an independent finite-element code under refinement (mixed u-p-J converges from above to "
        "6.947, degree-4 displacement from below to 6.918; tests/test_cooks_membrane.py). "
        "Quadratic B-splines, 3 Gauss points; the displacement formulation locks and approaches "
        "from below, the mixed one (each element's mean dilatation) from above. Tolerance: the "
        "three tips monotone and their Richardson limit within "
        f"{COOK_TOLERANCE['displacement']:.1%} (displacement) and "
        f"{COOK_TOLERANCE['mixed']:.1%} (mixed) of the reference.",
        "",
        "| formulation | spans per side | tip (mm) | relative error | wall time |",
        "|---|---|---|---|---|",
        f"| reference | | {REFERENCE_TIP} +- {REFERENCE_TIP_SPREAD} | | |",
    ]
    for formulation in ("displacement", "mixed"):
        f = cook[formulation]
        for lv in f["levels"]:
            lines.append(
                f"| {formulation} | {lv['spans']} | {lv['tip']:.4f} | "
                f"{relative_error(lv['tip'], REFERENCE_TIP):+.2%} | {lv['seconds']:.1f} s |"
            )
        if f["limit"] is not None:
            lines.append(
                f"| {formulation}, Richardson limit (observed order "
                f"{order(f['observed_order'])}) | | {f['limit']:.4f} | "
                f"{relative_error(f['limit'], REFERENCE_TIP):+.2%} | |"
            )
    lines += [
        "",
        "OpenGeoSys's published sequence of the same problem ([CooksMembraneFbar.py]"
        f"({OGS_URL}), its expected values): 4-node quadrilaterals, with F-bar and without. "
        "Its energy K/2 (J - 1)^2 + G/2 (tr(J^(-2/3) C) - 3) is nma's solid to O(G/K) = 2e-4. "
        "Its F-bar tips approach from below, nma's mixed ones from above; tolerance: every nma "
        f"mixed tip within {OGS_TOLERANCE:.0%} above OpenGeoSys's F-bar tip at "
        f"{OGS_ELEMENTS[-1]} elements.",
        "",
        "| elements per side | F-bar tip (mm) | relative error | without F-bar (mm) |",
        "|---|---|---|---|",
    ]
    for n, fbar, standard in zip(OGS_ELEMENTS, OGS_FBAR, OGS_STANDARD):
        lines.append(
            f"| {n} | {fbar:.4f} | {relative_error(fbar, REFERENCE_TIP):+.2%} | {standard:.4f} |"
        )
    return lines
