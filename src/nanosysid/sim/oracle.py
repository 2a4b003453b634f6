"""The oracle: a predictor that integrates the simulator's true dynamics, hidden effects included.

It is the physical limit of the benchmark on simulated data. What it still cannot know is the
measurement noise on ``y0`` and on ``u``, the rotor speeds between samples (it interpolates
linearly), and, with ``telemetry_delay``, the last rotor speeds of a window, which the delay
pushes past its end (it holds the last known one).
"""

from __future__ import annotations

import functools

import numpy as np
import torch
from torch import Tensor

from nanosysid import dynamics
from nanosysid.rollout import advance_inputs, as_tensor
from nanosysid.sim.world import World
from nanosysid.vehicle import Vehicle

__all__ = ["Oracle"]


class Oracle:
    """``predict(y0 (B, 13), u (B, H, 4)) -> (B, H, 13)`` with the true dynamics of ``world``."""

    def __init__(self, world: World, vehicle: Vehicle | None = None, *, dt: float = 0.01, substeps: int = 4,
                 rotor_delay: float | None = None) -> None:
        self.world = world
        # delay (s) of the rotor speeds in u behind the true ones: the telemetry_delay effect for
        # the simulator's direct output, 0 after the data pipeline has aligned the motor stream
        self.rotor_delay = world.telemetry_delay if rotor_delay is None else rotor_delay
        self.vehicle = vehicle or Vehicle()
        self.dt = dt
        self.substeps = substeps
        self._f = functools.partial(dynamics.quad_dynamics, **self.vehicle.dynamics_kwargs())

    def _true_rotor_speeds(self, u: Tensor) -> Tensor:
        """Undo the telemetry delay: the true speed at sample h was recorded at h + delay."""
        return advance_inputs(u, self.rotor_delay / self.dt)

    @torch.no_grad()
    def __call__(self, y0, u) -> np.ndarray:
        y = as_tensor(y0, torch.float64)
        om = self._true_rotor_speeds(as_tensor(u, torch.float64))  # (B, H, 4)
        # rotor speeds move linearly from one sample to the next; the last one is held
        om_next = torch.cat((om[:, 1:], om[:, -1:]), dim=1)
        om_dot = (om_next - om) / self.dt
        out = []
        for k in range(om.shape[1]):
            def f(x, w_rot, od=om_dot[:, k]):
                force, torque = self.world.wrench(x, w_rot, od, self.vehicle)
                return self._f(x, w_rot, force_body=force, torque_body=torque)

            def om_mid(j, h, k=k):
                return om[:, k] + om_dot[:, k] * (j + 0.5) * h

            y = dynamics.integrate(f, y, om_mid, dt=self.dt, substeps=self.substeps)
            out.append(y)
        return torch.stack(out, dim=1).numpy()
