"""Named physical effects that may explain where the nominal model and the measurements disagree.

Each candidate is a small set of features of state and input whose combination, with physical
coefficients ``theta``, is an extra body-frame wrench: ``[F_B; tau_B] = Phi(x, Omega, dOmega/dt) theta``
with ``Phi`` of shape ``(..., 6, P)``. The same function gives the regression's columns and
the augmented model's wrench, so what is fitted is what is simulated. ``telemetry_delay``
is the one nonlinear candidate: a delay of the recorded rotor speeds, found by search.

Rotor numbering, mixing matrix and spin directions are the paper's (see
:mod:`nanosysid.dynamics` and :mod:`nanosysid.sim.effects`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch
from torch import Tensor

from nanosysid import dynamics, so3
from nanosysid.vehicle import Vehicle

__all__ = ["Candidate", "CANDIDATES", "NOMINAL", "DELAY", "wrench_features", "CHANNELS"]

CHANNELS = ("F_x", "F_y", "F_z", "tau_x", "tau_y", "tau_z")
SPIN = (1.0, -1.0, 1.0, -1.0)  # rotor angular velocity along body z (M1, M3 counter-clockwise)

Features = Callable[[Tensor, Tensor, Tensor, Vehicle], Tensor]


@dataclass(frozen=True)
class Candidate:
    """One named effect.

    Attributes:
        name: The effect's name (the simulator's catalogue names where they match).
        description: What it is, physically.
        params: Names of its coefficients, with units.
        features: ``(x (..., 13), Omega (..., 4), dOmega/dt (..., 4), vehicle) -> (..., 6, P)``.
        touches: The benchmark quantities it acts on directly.
    """

    name: str
    description: str
    params: tuple[str, ...]
    features: Features | None
    touches: tuple[str, ...]


def _zeros(x: Tensor, P: int) -> Tensor:
    return torch.zeros(*x.shape[:-1], 6, P, dtype=x.dtype)


def _v_body(x: Tensor) -> Tensor:
    """Air velocity in the body frame (still air): ``R^T v``."""
    return so3.quat_rotate(so3.quat_conj(x[..., 6:10]), x[..., 3:6])


def _rotor_drag(x, om, om_dot, vehicle):
    vb = _v_body(x)
    s = om.sum(-1)
    phi = _zeros(x, 2)
    phi[..., 0, 0] = -s * vb[..., 0]
    phi[..., 1, 0] = -s * vb[..., 1]
    phi[..., 2, 1] = -s * vb[..., 2]
    return phi


def _body_drag(x, om, om_dot, vehicle):
    vb = _v_body(x)
    phi = _zeros(x, 2)
    phi[..., 0, 0] = -vb[..., 0].abs() * vb[..., 0]
    phi[..., 1, 0] = -vb[..., 1].abs() * vb[..., 1]
    phi[..., 2, 1] = -vb[..., 2].abs() * vb[..., 2]
    return phi


def _com_offset(x, om, om_dot, vehicle):
    thrust = vehicle.k_f * (om * om).sum(-1)
    phi = _zeros(x, 2)
    # torque of the thrust (0, 0, T) about a centre of mass at (r_x, r_y, 0): T (-r_y, r_x, 0)
    phi[..., 4, 0] = thrust
    phi[..., 3, 1] = -thrust
    return phi


def _mixer(vehicle: Vehicle, dtype) -> Tensor:
    return dynamics.mixer_matrix(k_f=vehicle.k_f, k_m=vehicle.k_m, arm=vehicle.arm, dtype=dtype)


def _motor_asymmetry(x, om, om_dot, vehicle):
    M = _mixer(vehicle, x.dtype)  # (4 wrench rows [T, tau_x, tau_y, tau_z], 4 rotors)
    phi = _zeros(x, 4)
    # rotor i with k_F (1 + d_i) and k_M (1 + d_i) adds d_i times its own column of the wrench
    phi[..., 2:, :] = M * (om * om).unsqueeze(-2)
    return phi


def _rotor_inertia(x, om, om_dot, vehicle):
    spin = torch.tensor(SPIN, dtype=x.dtype)
    h = (om * spin).sum(-1)  # rotor angular momentum along body z, per unit rotor inertia
    w = x[..., 10:13]
    phi = _zeros(x, 1)
    # gyroscopic torque -w x (0, 0, J_r h) and the reaction to spinning the rotors up
    phi[..., 3, 0] = -w[..., 1] * h
    phi[..., 4, 0] = w[..., 0] * h
    phi[..., 5, 0] = -(om_dot * spin).sum(-1)
    return phi


def _nominal(x, om, om_dot, vehicle):
    """Corrections of the nominal coefficients: k_F (thrust and roll/pitch torque) and k_M."""
    om2 = om * om
    phi = _zeros(x, 2)
    L = vehicle.arm
    phi[..., 2, 0] = om2.sum(-1)
    phi[..., 3, 0] = L * (-om2[..., 0] - om2[..., 1] + om2[..., 2] + om2[..., 3])
    phi[..., 4, 0] = L * (-om2[..., 0] + om2[..., 1] + om2[..., 2] - om2[..., 3])
    phi[..., 5, 1] = -om2[..., 0] + om2[..., 1] - om2[..., 2] + om2[..., 3]
    return phi


NOMINAL = Candidate("nominal", "the quadratic rotor model's own coefficients, refitted alongside",
                    ("dk_F [N s²/rad²]", "dk_M [N m s²/rad²]"), _nominal, ("p", "v", "R", "w"))

DELAY = Candidate("telemetry_delay", "the recorded rotor speeds lag the true ones by a delay",
                  ("delay [s]",), None, ("p", "v", "R", "w"))

CANDIDATES: dict[str, Candidate] = {c.name: c for c in (
    Candidate("rotor_drag", "blade flapping and induced drag: F_B = -(Σ Ω_i) diag(K_xy, K_xy, K_z) v_B",
              ("K_xy [kg/rad]", "K_z [kg/rad]"), _rotor_drag, ("p", "v")),
    Candidate("body_drag", "quadratic airframe drag: F_B = -diag(c_xy, c_xy, c_z) |v_B| v_B",
              ("c_xy [kg/m]", "c_z [kg/m]"), _body_drag, ("p", "v")),
    DELAY,
    Candidate("com_offset", "centre of mass at (r_x, r_y) off the geometric centre: tau = T (-r_y, r_x, 0)",
              ("r_x [m]", "r_y [m]"), _com_offset, ("R", "w")),
    Candidate("motor_asymmetry", "per-rotor coefficients k_F (1 + d_i), k_M (1 + d_i)",
              ("d_1 [-]", "d_2 [-]", "d_3 [-]", "d_4 [-]"), _motor_asymmetry, ("p", "v", "R", "w")),
    Candidate("rotor_inertia", "rotor inertia J_r: gyroscopic torque -ω × (0, 0, J_r Σ s_i Ω_i) and yaw "
              "reaction -J_r Σ s_i dΩ_i/dt", ("J_r [kg m²]",), _rotor_inertia, ("R", "w")),
)}


def wrench_features(names, x: Tensor, om: Tensor, om_dot: Tensor, vehicle: Vehicle) -> Tensor:
    """Features of the named candidates side by side, ``(..., 6, sum P)``."""
    parts = [(NOMINAL if n == "nominal" else CANDIDATES[n]).features(x, om, om_dot, vehicle) for n in names]
    return torch.cat(parts, dim=-1)
