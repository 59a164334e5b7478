"""Actuation over time: what a network's outputs mean as each actuator's waveform.

`Fourier`: d_k(t) = d_max tanh(c_k0 + sum_j (a_kj cos(2 pi j t / P) + b_kj sin(2 pi j t / P))) s(t),
a few harmonics of a period P per actuator, bounded by d_max as the static actuations are, and
started from rest by s(t), the quintic smootherstep over [0, ramp] (value, slope and curvature 0 at
t = 0, so the motion starts at rest with no jump in the boundary's acceleration).  Open loop: the
network sees the task's descriptor once and outputs the coefficients, so one trajectory is one
implicit solve chain and its adjoint one backward sweep.

`Pulse`: a fixed bump A 64 x^3 (1 - x)^3, x = t / duration on [0, 1] and 0 after (value, slope and
curvature 0 at both ends): an impulse on the actuated edge.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp

from .. import checks


def smootherstep(x):
    x = jnp.clip(x, 0.0, 1.0)
    return x * x * x * (x * (6.0 * x - 15.0) + 10.0)


@dataclass(frozen=True)
class Fourier:
    actuators: int
    harmonics: int
    period: float
    ramp: float
    d_max: float

    def __post_init__(self):
        where = "Fourier"
        checks.integer(where, "actuators", self.actuators, "[0, 1000000]")
        checks.integer(where, "harmonics", self.harmonics, "[0, 1000]")
        checks.number(where, "period", self.period, "(0, inf)")
        checks.number(where, "ramp", self.ramp, "[0, inf)")
        checks.number(where, "d_max", self.d_max, "(0, inf)")

    @property
    def n_coeffs(self) -> int:
        return self.actuators * (2 * self.harmonics + 1)

    def __call__(self, coeffs, t):
        """Each actuator's displacement at time t from the n_coeffs coefficients (per actuator:
        c_k0, then the cosines' and the sines' a_kj, b_kj)."""
        if jnp.shape(coeffs) != (self.n_coeffs,):
            raise ValueError(
                f"Fourier: coeffs must have shape ({self.n_coeffs},) "
                f"({self.actuators} actuators x (2 x {self.harmonics} harmonics "
                f"+ 1)), got {jnp.shape(coeffs)}"
            )
        c = coeffs.reshape(self.actuators, 2 * self.harmonics + 1)
        j = jnp.arange(1, self.harmonics + 1)
        phase = 2.0 * jnp.pi * j * t / self.period
        h = self.harmonics
        series = c[:, 0] + c[:, 1 : 1 + h] @ jnp.cos(phase) + c[:, 1 + h :] @ jnp.sin(phase)
        start = smootherstep(t / self.ramp) if self.ramp > 0 else 1.0
        return self.d_max * jnp.tanh(series) * start


@dataclass(frozen=True)
class Pulse:
    amplitude: float
    duration: float

    def __post_init__(self):
        checks.number("Pulse", "amplitude", self.amplitude)
        checks.number("Pulse", "duration", self.duration, "(0, inf)")

    def __call__(self, t):
        x = jnp.clip(t / self.duration, 0.0, 1.0)
        return self.amplitude * 64.0 * (x * (1.0 - x)) ** 3
