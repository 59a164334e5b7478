"""The dynamics' names, without JAX (the settings' schemas import them)."""
SCHEMES = ("newmark", "generalised_alpha")  # nma.dynamics.schemes.Scheme.of
