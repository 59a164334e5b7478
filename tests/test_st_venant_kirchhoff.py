"""St Venant-Kirchhoff (nma/mechanics/laws/st_venant_kirchhoff.py): its energy is the textbook
lambda/2 (tr E)^2 + mu tr(E^2) in plane strain; its small-strain moduli are linear elasticity's; its
uniaxial plane-strain stress is the closed form E'/2 (l^3 - l), E' = E / (1 - nu^2) (e.g. Holzapfel,
Nonlinear solid mechanics, sec. 6.5; Belytschko, Liu and Moran, sec. 5.4.2); it is refused where
it softens (below the stretch sqrt(1/3)); and a scene solves in it.  The uniaxial computation is
experiments/verification/st_venant_kirchhoff.py's, whose report (make verify) shows it beside the
closed form."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import brentq

from experiments.verification.st_venant_kirchhoff import SVK_E as E
from experiments.verification.st_venant_kirchhoff import SVK_NU as NU
from experiments.verification.st_venant_kirchhoff import lateral_stretch, svk_uniaxial_stress
from nma.errors import ConfigError
from nma.mechanics.laws import drucker_unstable, law_of, nominal_stress
from nma.mechanics.material import Material
from nma.schema import MaterialConfig
from nma.simulator import Simulator

MU, LAMBDA = E / (2 * (1 + NU)), E * NU / ((1 + NU) * (1 - 2 * NU))
PLANE = E / (1 - NU**2)  # uniaxial stress in plane strain: 4 mu (lambda + mu) / (lambda + 2 mu)
SVK = Material(law=law_of("st_venant_kirchhoff"))
P = jnp.array([E, NU])


def textbook(F):
    """lambda/2 (tr E)^2 + mu tr(E^2), E = (F^T F - I)/2, the 2 x 2 E of plane strain (E_33 = 0)."""
    Eg = 0.5 * (F.T @ F - np.eye(2))
    return 0.5 * LAMBDA * np.trace(Eg) ** 2 + MU * np.trace(Eg @ Eg)


def test_energy_is_the_textbook_green_lagrange_form_and_the_reference_is_free():
    rng = np.random.default_rng(5)
    Fs = np.eye(2) + 0.3 * rng.standard_normal((12, 2, 2))
    W, Pk, _ = SVK.point_terms(P)
    np.testing.assert_allclose(W(jnp.asarray(Fs)), [textbook(F) for F in Fs], rtol=1e-13)
    assert float(jnp.max(jnp.abs(Pk(jnp.eye(2))))) == 0.0  # stress-free, exactly
    assert float(SVK.moduli(P)[0]) == pytest.approx(MU, rel=1e-15)


def test_small_strain_moduli_are_linear_elasticitys():
    """The tangent dP/dF at rest is the linear plane-strain elasticity tensor lambda d_ij d_kl +
    mu (d_ik d_jl + d_il d_jk); the slope of uniaxial plane-strain stress is E / (1 - nu^2)."""
    d = np.eye(2)
    iso = LAMBDA * np.einsum("ij,kl->ijkl", d, d) + MU * (
        np.einsum("ik,jl->ijkl", d, d) + np.einsum("il,jk->ijkl", d, d)
    )
    np.testing.assert_allclose(SVK.point_terms(P)[2](jnp.eye(2)), iso, rtol=1e-13, atol=1e-16)
    eps = 1e-6  # P_11 at stretch 1 + eps: E' eps (1 + 3 eps / 2), its relative excess 1.5e-6
    F = jnp.diag(jnp.array([1.0 + eps, lateral_stretch(1.0 + eps)]))
    stress = SVK.point_terms(P)[1](F)
    assert abs(float(stress[1, 1])) < 1e-12 * PLANE
    np.testing.assert_allclose(float(stress[0, 0]) / eps, PLANE, rtol=2e-6)
    assert PLANE == pytest.approx(4 * MU * (LAMBDA + MU) / (LAMBDA + 2 * MU), rel=1e-14)


def test_uniaxial_nominal_stress_is_the_closed_form_at_finite_strain():
    """P_11 = E'/2 (l^3 - l) in uniaxial plane-strain stress at stretches 0.7 to 1.8, the lateral
    face free (P_22 = 0); its minimum is at l = sqrt(1/3), found here by a root of dP/dl."""
    lam = np.linspace(0.7, 1.8, 12)
    stress = svk_uniaxial_stress(lam)  # at F = diag(l, lateral_stretch(l))
    np.testing.assert_allclose(stress[:, 1, 1], 0.0, atol=1e-14)
    np.testing.assert_allclose(stress[:, 0, 0], PLANE / 2 * (lam**3 - lam), rtol=1e-12)
    p11 = jax.grad(lambda a: SVK.point_terms(P)[1](jnp.diag(jnp.stack([a, 1.0 + 0 * a])))[0, 0])
    # along F = diag(l, 1) (no lateral contraction) P_11 = (lambda + 2 mu)/2 (l^3 - l) too
    turn = brentq(lambda a: float(p11(a)), 0.3, 0.9)
    assert turn == pytest.approx(3**-0.5, rel=1e-12)


def test_stretches_below_the_turning_point_are_refused_naming_it():
    """The field's warning (unstable in strong compression): material.stretches reaching below
    sqrt(1/3) are refused; its own file's [0.6, 2.0] are accepted; no incompressible tests."""
    with pytest.raises(ConfigError, match=r"sqrt\(1/3\) = 0.577") as err:
        MaterialConfig(law="st_venant_kirchhoff", stretches=[0.5, 2.0])
    assert "material.stretches=[0.5, 2.0]: uniaxial compression at stretch 0.5 softens" in str(
        err.value
    )
    cfg = MaterialConfig.of_law("st_venant_kirchhoff")
    assert cfg.stretches == [0.6, 2.0] and cfg.values == {"E": 0.07}
    law = law_of("st_venant_kirchhoff")
    assert drucker_unstable(law, [E], (0.6, 3.0)) == ""
    assert "softens" in drucker_unstable(law, [E], (0.55, 3.0))
    with pytest.raises(ConfigError, match="no incompressible limit"):
        nominal_stress(law, [E], "uniaxial", 1.5)
    with pytest.raises(ConfigError, match="material.formulation=mixed .* has none"):
        Material("mixed", law)


def test_a_scene_solves_in_st_venant_kirchhoff():
    """The tutorial's strip, actuated, converges to a visible deformation in the displacement
    formulation (auto picks it: the law has no volume term)."""
    material = {"law": "st_venant_kirchhoff", "E": E, "nu": NU, "stretches": [0.6, 2.0]}
    fidelity = {"ctrl_per_patch": 5, "quad_points": 3}
    sim = Simulator.from_config("strip", fidelity, "superlu", material=material)
    eq = sim.solve(sim.init_params(), jnp.array([1.0, 0.5]), sim.material_params)
    assert eq.converged and np.all(np.isfinite(eq.u)) and float(np.max(np.abs(eq.u))) > 0.1
    assert sim.disc.material.formulation == "displacement"
