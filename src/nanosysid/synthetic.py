"""Small synthetic flights integrated with the project's own nominal dynamics.

These flights follow the quadratic rotor model exactly (no hidden effects, optional white
measurement noise), so the physics model with the same parameters predicts them to
integration accuracy. They serve tests and benchmarks that need data of a known origin.

The rotors are driven open loop by a smooth wrench: thrust oscillating around the weight and
body torques shaped so that the angular velocity oscillates with zero mean, which keeps the
attitude bounded over a flight of any length.
"""

from __future__ import annotations

import functools

import numpy as np
import torch

from nanosysid import dynamics
from nanosysid.dataio import Flight
from nanosysid.vehicle import Vehicle

__all__ = ["synthetic_flights"]


def synthetic_flights(
    names: list[str],
    n_samples: int,
    *,
    vehicle: Vehicle | None = None,
    dt: float = 0.01,
    substeps: int = 4,
    noise: float = 0.0,
    seed: int = 0,
) -> list[Flight]:
    """Integrate one flight per name, all flights advancing together as one batch.

    Args:
        names: Flight names, ``<trajectory>_<date>_run<k>``.
        n_samples: Samples per flight, at period ``dt``.
        vehicle: Physical parameters (the paper's by default).
        dt: Output sample period (s); the rotor speeds are held over each period.
        substeps: RK4 steps per sample period.
        noise: Standard deviation of white noise added to every output channel, in the
            channel's unit (quaternions are renormalised afterwards).
        seed: Seed of the random excitation and of the noise.

    Returns:
        Flights with ``t``, ``u``, ``y`` and the accelerometer extras ``a*_body``.
    """
    vehicle = vehicle or Vehicle()
    rng = np.random.default_rng(seed)
    F, T = len(names), n_samples
    t = np.arange(T) * dt
    # (F, 4, 1): one frequency, amplitude and phase per flight and wrench channel
    freq = rng.uniform(0.3, 1.5, size=(F, 4, 1))
    phase = rng.uniform(0, 2 * np.pi, size=(F, 4, 1))
    rate_amp = rng.uniform(0.5, 1.5, size=(F, 4, 1))  # rad/s amplitude of the body rates
    arg = 2 * np.pi * freq * t + phase  # (F, 4, T)
    thrust = vehicle.mass * vehicle.gravity * (1 + 0.15 * np.sin(arg[:, 0]))  # (F, T)
    J = np.asarray(vehicle.inertia)[None, :, None]
    # tau = J * d/dt(A sin(arg)): rates oscillate with zero mean
    tau = J * rate_amp[:, 1:] * 2 * np.pi * freq[:, 1:] * np.cos(arg[:, 1:])  # (F, 3, T)
    wrench = np.concatenate((thrust[:, None], tau), axis=1)  # (F, 4, T)
    M = dynamics.mixer_matrix(k_f=vehicle.k_f, k_m=vehicle.k_m, arm=vehicle.arm).numpy()
    omega_sq = np.einsum("ij,fjt->fti", np.linalg.inv(M), wrench)  # (F, T, 4)
    u = np.sqrt(np.clip(omega_sq, 0.0, None))

    f = functools.partial(dynamics.quad_dynamics, **vehicle.dynamics_kwargs())
    x = torch.zeros(F, 13, dtype=torch.float64)
    x[:, 2] = 1.0
    x[:, 9] = 1.0
    u_t = torch.from_numpy(u)
    ys = torch.empty(F, T, 13, dtype=torch.float64)
    for k in range(T):
        ys[:, k] = x
        x = dynamics.integrate(f, x, u_t[:, k], dt=dt, substeps=substeps)
    y = ys.numpy()
    if noise > 0:
        y = y + rng.normal(scale=noise, size=y.shape)
        y[..., 6:10] /= np.linalg.norm(y[..., 6:10], axis=-1, keepdims=True)
    specific_force = thrust / vehicle.mass  # (F, T), along body z
    flights = []
    for i, name in enumerate(names):
        extra = {
            "ax_body": np.zeros(T),
            "ay_body": np.zeros(T),
            "az_body": specific_force[i].copy(),
        }
        flights.append(Flight(name=name, t=t.copy(), u=u[i].copy(), y=y[i].copy(), extra=extra))
    return flights
