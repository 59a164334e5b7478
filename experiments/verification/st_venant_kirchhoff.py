"""St Venant-Kirchhoff, a homogeneous uniaxial plane-strain stress against its closed form
E'/2 (l^3 - l), E' = E / (1 - nu^2) (Holzapfel, Nonlinear solid mechanics, sec. 6.5;
tests/test_st_venant_kirchhoff.py)."""

from __future__ import annotations

import time

import numpy as np


SVK_E, SVK_NU = 0.07, 0.3
SVK_STRETCHES = (0.7, 0.85, 1.2, 1.5, 1.8)
SVK_TOLERANCE = 1e-12  # relative: the closed form is exact, so only rounding is left


def lateral_stretch(lam, nu=SVK_NU):
    """The stretch across a uniaxial plane-strain stress of stretch lam: S_22 = 0 gives
    E_22 = -nu / (1 - nu) E_11."""
    return np.sqrt(1.0 - nu / (1.0 - nu) * (lam**2 - 1.0))


def svk_closed_form(lam):
    """E'/2 (l^3 - l), E' = E / (1 - nu^2): uniaxial plane-strain nominal stress."""
    return SVK_E / (1 - SVK_NU**2) / 2 * (np.asarray(lam) ** 3 - np.asarray(lam))


def svk_uniaxial_stress(lam):
    """nma's nominal stress tensors at F = diag(l, lateral_stretch(l)), one per stretch."""
    import jax.numpy as jnp

    from nma.mechanics.laws import law_of
    from nma.mechanics.material import Material

    law = Material(law=law_of("st_venant_kirchhoff"))
    F = jnp.asarray([np.diag([a, lateral_stretch(a)]) for a in np.asarray(lam, float)])
    return np.asarray(law.point_terms(jnp.array([SVK_E, SVK_NU]))[1](F))


def run() -> dict:
    t0 = time.perf_counter()
    stress = svk_uniaxial_stress(SVK_STRETCHES)
    closed = svk_closed_form(SVK_STRETCHES)
    errors = stress[:, 0, 0] / closed - 1.0
    lateral = float(np.max(np.abs(stress[:, 1, 1])))
    seconds = time.perf_counter() - t0
    failures = []
    if np.max(np.abs(errors)) > SVK_TOLERANCE or lateral > SVK_TOLERANCE * np.max(np.abs(closed)):
        failures.append(
            f"St Venant-Kirchhoff: {np.max(np.abs(errors)):.2g} from the closed form "
            f"(lateral stress {lateral:.2g}), over {SVK_TOLERANCE:g}"
        )
    return {
        "E": SVK_E,
        "nu": SVK_NU,
        "stretches": list(SVK_STRETCHES),
        "closed_form": closed.tolist(),
        "nma": stress[:, 0, 0].tolist(),
        "relative_error": errors.tolist(),
        "max_lateral_stress": lateral,
        "seconds": seconds,
        "tolerance": SVK_TOLERANCE,
        "failures": failures,
    }


def section(svk: dict) -> list[str]:
    lines = [
        "## St Venant-Kirchhoff, uniaxial plane-strain stress",
        "",
        "A homogeneous deformation F = diag(l, l_2), the lateral stretch l_2 making P_22 = 0, in "
        f"nma's St Venant-Kirchhoff law (E = {SVK_E:g}, nu = {SVK_NU:g}): the nominal stress "
        "P_11 against the closed form E'/2 (l^3 - l), E' = E / (1 - nu^2) (Holzapfel, Nonlinear "
        "solid mechanics, sec. 6.5; Belytschko, Liu and Moran, sec. 5.4.2). One level: the "
        f"deformation is homogeneous. Tolerance: {SVK_TOLERANCE:g} relative (the largest P_22: "
        f"{svk['max_lateral_stress']:.1e}); computed in {svk['seconds']:.2f} s.",
        "",
        "| stretch l | closed form P_11 | nma P_11 | relative error |",
        "|---|---|---|---|",
    ]
    for lam, ref, value, err in zip(
        svk["stretches"], svk["closed_form"], svk["nma"], svk["relative_error"]
    ):
        lines.append(f"| {lam:g} | {ref:.10g} | {value:.10g} | {err:.1e} |")
    return lines
