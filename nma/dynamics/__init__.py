"""Dynamics: inertia and damping on the static model's discretisation, implicit time stepping by the
static Newton with its safeguards, the discrete adjoint through time, actuation waveforms and the
structure's natural frequencies."""
