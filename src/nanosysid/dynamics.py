"""Rigid-body quadrotor dynamics of the benchmark paper, as pure batched functions.

State ``x = [p, v, q, w]`` of shape ``(..., 13)``:

- ``p`` (m): position of the centre of mass in the world frame (z up);
- ``v`` (m/s): velocity in the world frame;
- ``q``: unit quaternion ``xyzw``, body to world (Hamilton);
- ``w`` (rad/s): angular velocity in the body frame.

Input ``u`` of shape ``(..., 4)``: rotor speeds ``Omega_1..4`` (rad/s), rotors numbered as in
the paper's 'x' layout (M1 front-right, M2 rear-right, M3 rear-left, M4 front-left); their
positions and spin directions are :data:`ROTOR_X`, :data:`ROTOR_Y` and :data:`SPIN`, from
which the mixing matrix is built.

Physical parameters are keyword-only arguments, so a partially applied function
(``functools.partial``) is a model of one vehicle.
"""

from __future__ import annotations

import functools
from typing import Callable, Sequence

import torch
import torch.nn.functional as F
from torch import Tensor

from nanosysid import so3

__all__ = [
    "GRAVITY",
    "ROTOR_X",
    "ROTOR_Y",
    "SPIN",
    "mixer_matrix",
    "signed_sum",
    "rotor_wrench",
    "quad_dynamics",
    "rk4_step",
    "integrate",
    "renormalise",
    "split_state",
]

GRAVITY = 9.81  # m/s^2, the paper's value

# The 'x' layout, body frame x forward, y left, z up: the sign of each rotor's x and y position
# (each at the lever arm L from the centre on both axes), and the direction of its angular
# velocity along body z (M1 and M3 turn counter-clockwise seen from above). The drag torque of
# a rotor turns the body against its spin: the yaw row of the mixer is ``-k_M SPIN``.
ROTOR_X = (1.0, -1.0, -1.0, 1.0)
ROTOR_Y = (-1.0, -1.0, 1.0, 1.0)
SPIN = (1.0, -1.0, 1.0, -1.0)


def split_state(x: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """``(p, v, q, w)`` views of a ``(..., 13)`` state."""
    return x[..., 0:3], x[..., 3:6], x[..., 6:10], x[..., 10:13]


@functools.lru_cache(maxsize=64)
def _constant(values: tuple, dtype: torch.dtype, device) -> Tensor:
    # rebuilding small constant tensors costs more than the arithmetic at batch sizes of
    # a few flights, where the simulator's 1 kHz loop spends its time
    return torch.tensor(values, dtype=dtype, device=device)


def mixer_matrix(*, k_f: float, k_m: float, arm: float, dtype=torch.float64, device=None) -> Tensor:
    """The paper's 'x' mixing matrix (equation thrust_torque_mapping), shape ``(4, 4)``.

    Maps squared rotor speeds (rad^2/s^2) to ``[T (N), tau_x, tau_y, tau_z (N m)]``.

    Args:
        k_f: Thrust coefficient (N s^2/rad^2).
        k_m: Moment coefficient (N m s^2/rad^2).
        arm: Effective lever arm L (m), the distance from the centre of mass to each rotor
            projected on the body x or y axis.
    """
    kl = k_f * arm
    rows = (
        (k_f,) * 4,
        tuple(kl * y for y in ROTOR_Y),  # tau_x = sum y_i T_i
        tuple(-kl * x for x in ROTOR_X),  # tau_y = -sum x_i T_i
        tuple(-k_m * s for s in SPIN),
    )
    return _constant(rows, dtype, device)


def signed_sum(signs: Sequence[float], values: Sequence):
    """``sum_i signs_i values_i`` for signs of +-1, as additions and subtractions only: the rows
    of the mixer over scalars or tensors alike (the generated C counts no multiplication)."""
    total = values[0] if signs[0] > 0 else -values[0]
    for sign, v in zip(signs[1:], values[1:]):
        total = total + v if sign > 0 else total - v
    return total


def rotor_wrench(u: Tensor, *, k_f: float, k_m: float, arm: float) -> tuple[Tensor, Tensor]:
    """Collective thrust ``T (...,)`` in N and body torque ``tau (..., 3)`` in N m."""
    M = mixer_matrix(k_f=k_f, k_m=k_m, arm=arm, dtype=u.dtype, device=u.device)
    wrench = (u * u) @ M.T  # (..., 4)
    return wrench[..., 0], wrench[..., 1:]


def quad_dynamics(
    x: Tensor,
    u: Tensor,
    *,
    mass: float,
    inertia: tuple[float, float, float] | Tensor,
    k_f: float,
    k_m: float,
    arm: float,
    gravity: float = GRAVITY,
    angular_dynamics: bool = True,
    force_body: Tensor | None = None,
    torque_body: Tensor | None = None,
) -> Tensor:
    """Time derivative of the state, the paper's equation (quad_dynamics).

    Args:
        x: State ``(..., 13)``, see the module docstring.
        u: Rotor speeds ``(..., 4)`` in rad/s.
        mass: Vehicle mass (kg).
        inertia: Diagonal of the body-frame inertia matrix J (kg m^2): three numbers, or a
            tensor broadcasting against ``x[..., :3]`` (one body per flight of a batch).
        k_f: Thrust coefficient (N s^2/rad^2).
        k_m: Moment coefficient (N m s^2/rad^2).
        arm: Effective lever arm L (m).
        gravity: Gravitational acceleration (m/s^2), acting along -z of the world frame.
        angular_dynamics: If False, ``dw/dt = 0``: the paper's nominal physics baseline,
            which keeps the measured angular velocity constant over the step.
        force_body: Extra force ``(..., 3)`` in N, body frame, added to the rotor thrust.
        torque_body: Extra torque ``(..., 3)`` in N m, body frame, added to the rotor torque.

    Returns:
        ``dx/dt`` of shape ``(..., 13)``.
    """
    _, v, q, w = split_state(x)
    thrust, tau = rotor_wrench(u, k_f=k_f, k_m=k_m, arm=arm)
    f_b = F.pad(thrust.unsqueeze(-1), (2, 0))  # [0, 0, T]
    if force_body is not None:
        f_b = f_b + force_body
    g = _constant((0.0, 0.0, -gravity), x.dtype, x.device)
    v_dot = so3.quat_rotate(q, f_b) / mass + g
    # q_dot = 1/2 q ⊗ [w, 0], in vector form (a few ops instead of a full product)
    qv, qw = q[..., :3], q[..., 3:]
    q_dot = 0.5 * torch.cat((qw * w + torch.linalg.cross(qv, w, dim=-1), -(qv * w).sum(-1, keepdim=True)), dim=-1)
    if angular_dynamics:
        J = inertia if isinstance(inertia, Tensor) else _constant(tuple(inertia), x.dtype, x.device)
        if torque_body is not None:
            tau = tau + torque_body
        w_dot = (tau - torch.linalg.cross(w, J * w, dim=-1)) / J
    else:
        w_dot = torch.zeros_like(w)
    return torch.cat((v, v_dot, q_dot, w_dot), dim=-1)


def rk4_step(f: Callable[..., Tensor], x: Tensor, u: Tensor, dt: float, t=None) -> Tensor:
    """One classical Runge-Kutta step of ``dx/dt = f(x, u)`` with ``u`` held over the step; of
    ``dx/dt = f(x, u, t)`` when the step's start time ``t`` (s; a float or a tensor) is given.

    ``x`` is anything with ``+`` and multiplication by a float: a tensor, or the vector of
    traced scalars the C generator runs it on.
    """
    if t is None:
        k1 = f(x, u)
        k2 = f(x + 0.5 * dt * k1, u)
        k3 = f(x + 0.5 * dt * k2, u)
        k4 = f(x + dt * k3, u)
    else:
        k1 = f(x, u, t)
        k2 = f(x + 0.5 * dt * k1, u, t + 0.5 * dt)
        k3 = f(x + 0.5 * dt * k2, u, t + 0.5 * dt)
        k4 = f(x + dt * k3, u, t + dt)
    return x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def renormalise(y: Tensor) -> Tensor:
    """The state ``(..., 13+)`` with its quaternion scaled back to unit norm."""
    return torch.cat((y[..., :6], so3.quat_normalize(y[..., 6:10]), y[..., 10:]), dim=-1)


def integrate(f: Callable, y, u, *, dt: float, substeps: int, normalise: Callable = renormalise, t=None):
    """One sample period of every physics-based step: ``substeps`` RK4 steps of ``dx/dt = f(x, u)``,
    then the quaternion renormalised (RK4 leaves the unit sphere by O(h^5) per step; this keeps
    long rollouts on SO(3) without changing the rotation).

    Args:
        f: ``f(x, u) -> dx/dt``.
        y: State at the start of the period, ``(..., 13)``.
        u: The input, held over the period; or ``u(j, h)``, the input of substep ``j`` of
            ``h`` seconds (an input that moves within the period).
        dt: The sample period (s).
        substeps: RK4 steps per period.
        normalise: Renormalisation of the quaternion; the C generator passes its scalar one.
        t: Time (s) at the start of the period, for an ``f(x, u, t)`` that depends on time.
    """
    if substeps < 1:
        raise ValueError(f"substeps must be >= 1, got {substeps}")
    h = dt / substeps
    for j in range(substeps):
        y = rk4_step(f, y, u(j, h) if callable(u) else u, h, None if t is None else t + j * h)
    return normalise(y)
