"""nma: neuromechanical autoencoders, a differentiable isogeometric elasticity simulator and
platform."""

__version__ = "0.1.0"
