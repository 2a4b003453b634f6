"""The nominal physics model: RK4 of the rigid-body dynamics with the quadratic rotor model."""

from __future__ import annotations

import functools

import numpy as np
from torch import Tensor, nn

from nanosysid import dynamics
from nanosysid.vehicle import Vehicle

__all__ = ["PhysicsStep", "naive_predict"]


class PhysicsStep(nn.Module):
    """Discrete-time map ``y_{t+1} = f_phys(y_t, u_t)``: RK4 over one sample period.

    Args:
        vehicle: Physical parameters.
        dt: Sample period (s).
        substeps: RK4 steps per sample period.
        angular_dynamics: False gives the paper's ``physics`` baseline (``dw/dt = 0``);
            True keeps the torque equation (``physics_full``).
    """

    def __init__(
        self,
        vehicle: Vehicle,
        *,
        dt: float = 0.01,
        substeps: int = 1,
        angular_dynamics: bool = False,
    ) -> None:
        super().__init__()
        if substeps < 1:
            raise ValueError(f"substeps must be >= 1, got {substeps}")
        self.vehicle = vehicle
        self.dt = dt
        self.substeps = substeps
        self.angular_dynamics = angular_dynamics
        self._f = functools.partial(
            dynamics.quad_dynamics, **vehicle.dynamics_kwargs(), angular_dynamics=angular_dynamics
        )

    def forward(self, y: Tensor, u: Tensor) -> Tensor:
        return dynamics.integrate(self._f, y, u, dt=self.dt, substeps=self.substeps)


def naive_predict(y0, u):
    """The paper's naive baseline: the output stays at ``y0`` over the whole horizon."""
    H = u.shape[1]
    if isinstance(y0, Tensor):
        return y0.unsqueeze(1).expand(-1, H, -1).clone()
    return np.repeat(y0[:, None, :], H, axis=1)
