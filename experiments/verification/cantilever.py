"""The cantilever: a slender clamped solid strip (L/h = 20), its first four in-plane bending
frequencies (nma.dynamics.modes) against Euler-Bernoulli and Timoshenko beam theory, both solved
here from their frequency equations with the modulus nma's plane model has
(tests/test_beam_frequencies.py; the strip is also the dynamics and body-force tests' BEAM)."""

from __future__ import annotations

import time

import numpy as np
from scipy.linalg import expm
from scipy.optimize import brentq

from .common import order, richardson_or_none


CELLS = 20
L, H = 5.0 * CELLS, 5.0
BEAM = {
    "name": "beam",
    "cell_size": 5.0,
    "cells": "S" * CELLS,
    "groups": [],
    "supports": [{"segment": [[0, 0], [0, H]], "kind": "clamped"}],
    "tracked": {"tip": [L, H / 2]},
    # the paper's volume term, whose plane modulus the report states beside the textbook's
    "volumetric": "bulk",
}
RHO, SHEAR_COEFFICIENT, MODES = 1.0, 5.0 / 6.0, 4
AREA, INERTIA = H, H**3 / 12.0  # per unit thickness
BEAM_LADDER = (5, 8, 11)  # control points per patch, 4 Gauss points
# |nma / Timoshenko - 1| per mode: at every level (the coarse test's), at the finest (the refined's)
BEAM_TOLERANCE, BEAM_FINE_TOLERANCE = 0.012, 0.005


def euler_bernoulli_roots(n):
    """The first n roots of cos(x) cosh(x) + 1 = 0 (clamped-free), bracketed near (k - 1/2) pi."""
    f = lambda x: np.cos(x) * np.cosh(x) + 1.0
    return np.array([brentq(f, (k + 0.5) * np.pi - 1.2, (k + 0.5) * np.pi + 1.2) for k in range(n)])


def euler_bernoulli_frequencies(E, n):
    return euler_bernoulli_roots(n) ** 2 * np.sqrt(E * INERTIA / (RHO * AREA * L**4))


def timoshenko_frequencies(E, G, n):
    """The first n angular frequencies of the clamped-free Timoshenko beam: y = (w, phi, V, M) with
    w' = phi + V / (k G A), phi' = M / (E I), V' = -rho A w^2 w, M' = -V - rho I w^2 phi; the
    clamped end w = phi = 0, the free end V = M = 0, so det of the (V, M) block of expm(A L) over
    the starts (V, M) = (1, 0), (0, 1) is zero at a natural frequency."""

    def det(omega):
        A = np.zeros((4, 4))
        A[0, 1], A[0, 2] = 1.0, 1.0 / (SHEAR_COEFFICIENT * G * AREA)
        A[1, 3] = 1.0 / (E * INERTIA)
        A[2, 0] = -RHO * AREA * omega**2
        A[3, 1], A[3, 2] = -RHO * INERTIA * omega**2, -1.0
        T = expm(A * L)
        return np.linalg.det(T[2:, 2:])

    grid = np.linspace(1e-6, 1.5, 301) * euler_bernoulli_frequencies(E, n)[-1]
    values = [det(w) for w in grid]
    roots = [
        brentq(det, a, b)
        for a, b, fa, fb in zip(grid, grid[1:], values, values[1:])
        if np.sign(fa) != np.sign(fb)
    ]
    return np.array(roots[:n])


def plane_moduli(sim):
    """(E', G) from the model's tangent at rest (nma.mechanics.material.Material.plane_moduli)."""
    E, _, G = sim.disc.material.plane_moduli(sim.material_params)
    return float(E), float(G)


def bending_frequencies(sim, n):
    """The first n frequencies whose modes move mostly across the strip (the axial mode between
    the third and fourth bending ones left out)."""
    from nma.dynamics.modes import natural_modes

    X = sim.reference_points(sim.init_params())
    omega, modes = natural_modes(sim, X, sim.material_params, RHO, count=n + 2)
    free = np.asarray(sim.equations.free)
    bending = []
    for w, m in zip(omega, modes):
        v = np.zeros(2 * sim.disc.mesh.n_points)
        v[free] = m
        v = v.reshape(-1, 2)
        if np.sum(v[:, 1] ** 2) > 0.5 * np.sum(v**2):
            bending.append(w)
    return np.array(bending[:n])


def compare(omega, E, G):
    """The model's frequencies' relative errors against Euler-Bernoulli and Timoshenko."""
    eb, timo = euler_bernoulli_frequencies(E, MODES), timoshenko_frequencies(E, G, MODES)
    return omega / eb - 1.0, omega / timo - 1.0


def beam_simulator(fidelity: dict):
    from nma.simulator import Simulator

    return Simulator.from_config(BEAM, fidelity=fidelity, solver="superlu")


def run() -> dict:
    levels, failures = [], []
    for ctrl in BEAM_LADDER:
        t0 = time.perf_counter()
        sim = beam_simulator({"quad_points": 4, "ctrl_per_patch": ctrl})
        omega = bending_frequencies(sim, MODES)
        E, G = plane_moduli(sim)
        eb, timo = euler_bernoulli_frequencies(E, MODES), timoshenko_frequencies(E, G, MODES)
        levels.append(
            {
                "ctrl_per_patch": ctrl,
                "omega": omega.tolist(),
                "error_euler_bernoulli": (omega / eb - 1.0).tolist(),
                "error_timoshenko": (omega / timo - 1.0).tolist(),
                "seconds": time.perf_counter() - t0,
            }
        )
    E_nu = [float(x) for x in sim.material_params]
    spans = [c - 2 for c in BEAM_LADDER]
    orders = [richardson_or_none(spans, [lv["omega"][m] for lv in levels])[1] for m in range(MODES)]
    for lv in levels:
        worst = max(abs(e) for e in lv["error_timoshenko"])
        if worst > BEAM_TOLERANCE:
            failures.append(
                f"cantilever at ctrl_per_patch {lv['ctrl_per_patch']}: {worst:.2%} from "
                f"Timoshenko, over {BEAM_TOLERANCE:.1%}"
            )
    worst = max(abs(e) for e in levels[-1]["error_timoshenko"])
    if worst > BEAM_FINE_TOLERANCE:
        failures.append(
            f"cantilever at the finest level: {worst:.2%} from Timoshenko, over "
            f"{BEAM_FINE_TOLERANCE:.1%}"
        )
    if not np.all(np.diff([lv["omega"] for lv in levels], axis=0) < 0):
        failures.append("cantilever: the frequencies do not fall under refinement (Rayleigh-Ritz)")
    return {
        "E": E_nu[0],
        "nu": E_nu[1],
        "plane_modulus": float(E),
        "shear_modulus": float(G),
        "plane_modulus_over_textbook": float(E / (E_nu[0] / (1 - E_nu[1] ** 2))),
        "euler_bernoulli": eb.tolist(),
        "timoshenko": timo.tolist(),
        "levels": levels,
        "observed_order": orders,
        "tolerance": {"every_level": BEAM_TOLERANCE, "finest": BEAM_FINE_TOLERANCE},
        "failures": failures,
    }


def section(beam: dict) -> list[str]:
    lines = [
        "## The cantilever's natural frequencies",
        "",
        f"A clamped solid strip, L = {L:g}, h = {H:g} (L/h = {L / H:g}), density {RHO:g}, "
        f"E = {beam['E']:g}, nu = {beam['nu']:g}: its first four in-plane bending frequencies "
        "(rad per unit time, nma.dynamics.modes, 4 Gauss points) against Euler-Bernoulli "
        "(cos x cosh x = -1) and Timoshenko (shear coefficient 5/6, rotary inertia), both solved "
        "in experiments/verification/cantilever.py. The beam theories take nma's plane modulus "
        f"E' = {beam['plane_modulus']:.5g}, {beam['plane_modulus_over_textbook']:.3f} times the "
        "textbook's plane-strain E / (1 - nu^2) (read from the model's small-strain tangent, "
        f"which its volume term sets), and G = mu = {beam['shear_modulus']:.5g}. "
        "Euler-Bernoulli leaves out shear "
        "and rotary inertia, which the plane continuum has: it is shown, not held. Tolerance: "
        f"within {BEAM_TOLERANCE:.1%} of Timoshenko at every level, {BEAM_FINE_TOLERANCE:.1%} at "
        "the finest (the 2D clamp and k = 5/6 leave about 0.2-0.4%), frequencies falling under "
        "refinement.",
        "",
        "| | mode 1 | mode 2 | mode 3 | mode 4 | wall time |",
        "|---|---|---|---|---|---|",
        "| Euler-Bernoulli | " + " | ".join(f"{w:.6g}" for w in beam["euler_bernoulli"]) + " | |",
        "| Timoshenko | " + " | ".join(f"{w:.6g}" for w in beam["timoshenko"]) + " | |",
    ]
    for lv in beam["levels"]:
        cells = [
            f"{w:.6g} ({et:+.2%}; EB {eb:+.2%})"
            for w, et, eb in zip(lv["omega"], lv["error_timoshenko"], lv["error_euler_bernoulli"])
        ]
        lines.append(
            f"| nma, {lv['ctrl_per_patch']} ctrl per patch | "
            + " | ".join(cells)
            + f" | {lv['seconds']:.1f} s |"
        )
    return lines + [
        "| observed order (Richardson, spans per patch "
        + ", ".join(str(c - 2) for c in BEAM_LADDER)
        + ") | "
        + " | ".join(order(p) for p in beam["observed_order"])
        + " | |",
        "",
        "In brackets: the relative error against Timoshenko, then against Euler-Bernoulli.",
    ]
