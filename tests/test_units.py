"""Physical units (nma.units) and the forces the actuators push with
(Simulator.actuation_forces)."""

import jax.numpy as jnp
import numpy as np
import pytest

from nma.mechanics.material import material
from nma.schema import MaterialConfig, PartConfig
from nma.units import Units


def test_an_actuators_force_is_the_energys_derivative_in_its_actuation(simulator):
    """At equilibrium (no dead load) dW(u(d))/dd = the force conjugate to d (the envelope theorem:
    the free dofs' residual is zero), so the reaction by automatic differentiation equals central
    differences of the equilibrium energy (step 1e-4: truncation ~1e-8 relative)."""
    sim = simulator("translation", ctrl_per_patch=5, quad_points=2)
    X = sim.reference_points(sim.init_params())
    mat = material(0.07, 0.3)
    d, h = jnp.array([1.2, -0.8]), 1e-4
    u = sim.solve(sim.init_params(), d, mat).u
    forces = np.asarray(sim.actuation_forces(X, u, mat))

    def energy(dd):
        return sim.energy(X, sim.solve(sim.init_params(), dd, mat).u, mat)

    fd = [(energy(d.at[k].add(h)) - energy(d.at[k].add(-h))) / (2 * h) for k in range(2)]
    np.testing.assert_allclose(forces, fd, rtol=1e-5)
    assert forces[0] * d[0] > 0 and forces[1] * d[1] > 0  # each actuator pushes along its own move


@pytest.mark.parametrize(
    "unit, newtons", [("MPa", 2.0 * 10.0), ("kPa", 2.0 * 10.0 * 1e-3), ("Pa", 2.0 * 10.0 * 1e-6)]
)
def test_a_force_in_newtons_is_stress_times_scale_times_thickness(unit, newtons):
    """F [N] = F [stress x length unit] x (MPa per stress unit) x scale [mm] x thickness [mm]: 1 MPa
    = 1 N/mm^2."""
    units = Units.of(PartConfig(scale=2.0, thickness=10.0), MaterialConfig(unit=unit))
    assert units.newton_per_force == pytest.approx(newtons, rel=1e-15)
    assert units.physical("f", [1.0, -0.5], "force") == {
        "f_N": pytest.approx([newtons, -0.5 * newtons])
    }
    assert units.physical("e", 3.0, "length") == {"e_mm": 6.0}


def test_without_a_stated_unit_nothing_is_converted():
    """Lengths need part.scale; forces need part.scale, part.thickness and material.unit."""
    assert Units.of(PartConfig(), MaterialConfig()).record()["length"] == "length units"
    for part, unit in (
        (PartConfig(scale=2.0), "MPa"),
        (PartConfig(scale=2.0, thickness=1.0), None),
    ):
        units = Units.of(part, MaterialConfig(unit=unit))
        assert units.physical("f", 1.0, "force") == {} and units.force_name != "N"
    assert Units.of(PartConfig(scale=2.0), MaterialConfig()).physical("e", 1.0, "length") == {
        "e_mm": 2.0
    }
    assert Units.of(PartConfig(scale=2.0), MaterialConfig()).physical("a", 1.0, None) == {}
