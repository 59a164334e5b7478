"""Dynamics: inertia and damping on the static model's discretisation, implicit time stepping by the
static Newton with its safeguards, the discrete adjoint through time, actuation waveforms and the
structure's natural frequencies.  A trajectory is three parts chosen by name (nma.dynamics.options):
the scheme (schemes/), the step control (controllers/) and the adjoint (adjoints/);
Simulator.dynamics builds one from the `dynamics` settings (nma.dynamics.trajectory.Dynamics)."""
