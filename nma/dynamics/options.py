"""The dynamics' names and ranges, without JAX (the settings' schemas import them)."""
SCHEMES = ("newmark", "generalised_alpha")  # nma.dynamics.schemes.Scheme.of
# the time stepping's settings, each an interval in the config's notation: DynamicsConfig's fields
# (nma.schema.physics) and Dynamics' arguments (nma.dynamics.checks)
RANGES = {"rho_inf": "[0, 1]", "dt": "(0, inf)", "steps": "[1, 1000000]", "alpha": "[0, inf)",
          "beta": "[0, inf)", "max_cuts": "[0, 20]"}
