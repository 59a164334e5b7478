"""Turek and Hron's CSM1 and CSM2 (Turek and Hron 2006, "Proposal for numerical benchmarking of
fluid-structure interaction between an elastic object and laminar incompressible flow", the CSM
tests, and the FEATFLOW benchmark tables): the elastic flag alone, St Venant-Kirchhoff, under
gravity, the displacement of its tip's midpoint A against CSM1 (-7.187e-3, -66.10e-3) m and CSM2
(-0.4690e-3, -16.97e-3) m. The flag is the rectangle from the chord where its edges meet the
cylinder, clamped there (experiments/verification/turek_hron.py says why, and what the 1.0 mm sliver
between chord and arc costs); make verify's report shows the ladder."""

import numpy as np
import pytest

from experiments.verification import turek_hron as th


@pytest.fixture(scope="module")
def flag():
    return th.flag_simulator(8)


def test_the_flag_is_the_benchmarks_in_si_units(flag):
    """Turek and Hron's CSM parameters: rho_s = 1000 kg/m^3, nu_s = 0.4, mu_s = 0.5e6 Pa (CSM1) and
    2e6 Pa (CSM2), g = 2 m/s^2; the flag meets the cylinder (radius 0.05 about (0.2, 0.2)) at x =
    0.2 + sqrt(0.05^2 - 0.01^2) and ends at A = (0.6, 0.2)."""
    assert th.LENGTH == pytest.approx(0.6 - 0.2 - np.sqrt(0.05**2 - 0.01**2), rel=1e-15)
    assert 0.35 < th.LENGTH < 0.3511
    sim = flag
    E, nu = (float(x) for x in sim.material_params)
    assert (E, nu) == (1.4e6, 0.4)  # E = 2 mu (1 + nu)
    assert sim.disc.body_force == (0.0, -2000.0)  # rho g, N/m^3
    assert sim.disc.material.law.name == "st_venant_kirchhoff"


def test_csm1_and_csm2_tips_within_half_a_percent_of_turek_and_hron(flag):
    """At 8 control points per patch (18 cells of 19.5 x 20 mm) both components of both cases
    within 0.5% of the published values (found +0.06% to +0.10%: the coarse mesh's stiffness
    offsets the straight clamp's flexibility, about +0.2% to +0.35% on the finest mesh)."""
    tips = th.tip_displacements(8, sim=flag)
    for name, case in th.CASES.items():
        np.testing.assert_allclose(tips[name], case["reference"], rtol=th.TOLERANCE)


@pytest.mark.slow  # three meshes and the bracket: about twenty seconds
def test_csm_tips_converge_from_below_and_the_two_clamps_bracket_them():
    """Under refinement (5, 8, 11 control points per patch) |u(A)| grows (a conforming
    displacement model is too stiff on a coarse mesh), the finest is within 0.5% of the reference
    (found +0.19% and +0.34% in CSM1's u_y and u_x), and the flag clamped at the arc's middle (L
    = 0.35) is stiffer than the reference (found -0.9% and -1.6%): the chord's clamp and the
    middle's bracket the benchmark's curved one."""
    r = th.run()
    assert r["failures"] == [], r["failures"]
    for name, case in th.CASES.items():
        finest = np.array(r["levels"][-1][name])
        short = np.array(r[name]["nominal_length"])
        ref = np.array(case["reference"])
        assert np.all(np.abs(finest) > np.abs(ref)) and np.all(np.abs(short) < np.abs(ref))
        np.testing.assert_allclose(finest, ref, rtol=th.TOLERANCE)
