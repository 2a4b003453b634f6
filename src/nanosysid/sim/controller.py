"""The Crazyflie firmware's Mellinger geometric controller with its integral terms, batched.

Follows ``controller_mellinger.c``: a force-level PID on position with acceleration
feed-forward, collective thrust as the projection of the desired force on the body z axis,
the attitude error ``e_R = vee(R_d^T R - R^T R_d)`` (the firmware omits the usual 1/2), a
rate term on the gyro, a derivative of the roll/pitch rate error, and a yaw attitude
integral. The firmware's gains are in PWM units; :class:`MellingerGains` holds them
converted to SI units for the CF2.1 Brushless (facts file, section 11). The power
distribution inverts the nominal mixing matrix and caps per-motor thrust as the firmware
does (excess above the maximum is removed from all four, which keeps the attitude part).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch
from torch import Tensor

from nanosysid import dynamics, so3
from nanosysid.vehicle import Vehicle

__all__ = ["MellingerGains", "Mellinger", "ControllerState"]


@dataclass(frozen=True)
class MellingerGains:
    """Gains in SI units. Position gains in N/m, N/(m/s), N/(m s); attitude gains in N m per
    unit of e_R (about 2 rad^-1 per rad), N m/(rad/s), N m/(rad/s^2); integral limits in m s
    and rad s. Firmware defaults: kp_xy 0.4, kd_xy 0.2, ki_xy 0.05, kp_z 1.25, kd_z 0.4,
    ki_z 0.05 (force level, times the 1.61 collective scale of the CF2.1 Brushless mixer);
    kR_xy 70000, kw_xy 20000, kR_z 60000, kw_z 12000, ki_m_z 500, kd_omega_rp 200 PWM units
    (2.16e-7 N m per PWM unit in roll/pitch, 6.95e-8 in yaw)."""

    kp_xy: float = 0.644
    kd_xy: float = 0.322
    ki_xy: float = 0.0805
    i_range_xy: float = 2.0
    kp_z: float = 2.01
    kd_z: float = 0.644
    ki_z: float = 0.0805
    i_range_z: float = 0.4
    kR_xy: float = 0.0151
    kw_xy: float = 4.32e-3
    ki_m_xy: float = 0.0
    i_range_m_xy: float = 1.0
    kR_z: float = 4.17e-3
    kw_z: float = 8.34e-4
    ki_m_z: float = 3.48e-5
    i_range_m_z: float = 1500.0
    kd_omega_rp: float = 4.32e-5

    @classmethod
    def from_mapping(cls, cfg) -> "MellingerGains":
        names = {f.name for f in fields(cls)}
        unknown = set(cfg) - names
        if unknown:
            raise KeyError(f"controller gains: unknown keys {sorted(unknown)}")
        return cls(**{k: float(v) for k, v in cfg.items()})


@dataclass
class ControllerState:
    """Integrators and the previous rate error, one row per flight."""

    i_pos: Tensor  # (B, 3), m s
    i_att: Tensor  # (B, 3), rad s
    prev_ew: Tensor  # (B, 3), rad/s

    @classmethod
    def zeros(cls, batch: int, dtype=torch.float64) -> "ControllerState":
        z = torch.zeros(batch, 3, dtype=dtype)
        return cls(z.clone(), z.clone(), z.clone())


class Mellinger:
    """Batched Mellinger controller producing per-motor speed commands (rad/s).

    Args:
        vehicle: Nominal parameters the controller assumes (mass, k_f, k_m, arm).
        gains: Controller gains.
        dt: Controller period (s), 2 ms in the firmware.
        omega_min: Idle rotor speed (rad/s) while armed.
        omega_max: Maximum rotor speed (rad/s).
    """

    def __init__(self, vehicle: Vehicle, gains: MellingerGains, *, dt: float = 0.002,
                 omega_min: float = 500.0, omega_max: float = 2900.0) -> None:
        self.v, self.g, self.dt = vehicle, gains, dt
        self.f_min = vehicle.k_f * omega_min**2
        self.f_max = vehicle.k_f * omega_max**2
        M = dynamics.mixer_matrix(k_f=vehicle.k_f, k_m=vehicle.k_m, arm=vehicle.arm)
        # (4, 4): wrench [T, tau] -> per-motor thrust f_i = k_f Omega_i^2
        self.alloc = torch.linalg.inv(M) * vehicle.k_f
        g = gains
        self.kp = torch.tensor([g.kp_xy, g.kp_xy, g.kp_z], dtype=torch.float64)
        self.kd = torch.tensor([g.kd_xy, g.kd_xy, g.kd_z], dtype=torch.float64)
        self.ki = torch.tensor([g.ki_xy, g.ki_xy, g.ki_z], dtype=torch.float64)
        self.i_lim = torch.tensor([g.i_range_xy, g.i_range_xy, g.i_range_z], dtype=torch.float64)
        self.kR = torch.tensor([g.kR_xy, g.kR_xy, g.kR_z], dtype=torch.float64)
        self.kw = torch.tensor([g.kw_xy, g.kw_xy, g.kw_z], dtype=torch.float64)
        self.kiR = torch.tensor([g.ki_m_xy, g.ki_m_xy, g.ki_m_z], dtype=torch.float64)
        self.iR_lim = torch.tensor([g.i_range_m_xy, g.i_range_m_xy, g.i_range_m_z], dtype=torch.float64)
        self.kdw = torch.tensor([g.kd_omega_rp, g.kd_omega_rp, 0.0], dtype=torch.float64)
        self.gravity = torch.tensor([0.0, 0.0, vehicle.gravity], dtype=torch.float64)

    def __call__(self, x: Tensor, p_ref: Tensor, v_ref: Tensor, a_ref: Tensor,
                 state: ControllerState, yaw_ref: Tensor | None = None) -> tuple[Tensor, ControllerState]:
        """One control period.

        Args:
            x: Estimated state ``(B, 13)``.
            p_ref, v_ref, a_ref: Setpoints ``(B, 3)`` in m, m/s, m/s^2.
            yaw_ref: Yaw setpoint ``(B,)`` in rad; None is zero.

        Returns:
            Rotor speed commands ``(B, 4)`` in rad/s, and the updated controller state.
        """
        p, v, q, w = dynamics.split_state(x)
        dt = self.dt
        e_p, e_v = p_ref - p, v_ref - v
        i_pos = torch.clamp(state.i_pos + e_p * dt, -self.i_lim, self.i_lim)
        F = self.v.mass * (a_ref + self.gravity) + self.kp * e_p + self.kd * e_v + self.ki * i_pos  # (B, 3)
        R = so3.quat_to_rotmat(q)  # (B, 3, 3), body to world
        thrust = (F * R[..., 2]).sum(-1)  # (B,), projection on the body z axis
        # desired attitude: z along F, heading from the yaw reference
        z_d = F / F.norm(dim=-1, keepdim=True).clamp_min(1e-9)
        x_c = torch.zeros_like(z_d)
        if yaw_ref is None:
            x_c[:, 0] = 1.0
        else:
            x_c[:, 0], x_c[:, 1] = torch.cos(yaw_ref), torch.sin(yaw_ref)
        y_d = torch.linalg.cross(z_d, x_c, dim=-1)
        y_d = y_d / y_d.norm(dim=-1, keepdim=True).clamp_min(1e-9)
        x_d = torch.linalg.cross(y_d, z_d, dim=-1)
        R_d = torch.stack((x_d, y_d, z_d), dim=-1)
        E = R_d.transpose(-1, -2) @ R - R.transpose(-1, -2) @ R_d
        e_R = torch.stack((E[:, 2, 1], E[:, 0, 2], E[:, 1, 0]), dim=-1)  # vee, no 1/2 as in firmware
        e_w = w  # the reference body rate is zero in position mode
        i_att = torch.clamp(state.i_att - e_R * dt, -self.iR_lim, self.iR_lim)
        tau = -self.kR * e_R - self.kw * e_w + self.kiR * i_att - self.kdw * (e_w - state.prev_ew) / dt
        # the firmware zeroes the moments and resets the integrators when thrust is not positive
        up = (thrust > 0).unsqueeze(-1)
        tau = torch.where(up, tau, torch.zeros_like(tau))
        i_pos = torch.where(up, i_pos, torch.zeros_like(i_pos))
        i_att = torch.where(up, i_att, torch.zeros_like(i_att))
        wrench = torch.cat((thrust.clamp_min(0).unsqueeze(-1), tau), dim=-1)  # (B, 4)
        f = wrench @ self.alloc.T  # (B, 4) per-motor thrust, N
        excess = (f.max(dim=-1, keepdim=True).values - self.f_max).clamp_min(0)
        f = (f - excess).clamp(self.f_min, self.f_max)
        omega_cmd = torch.sqrt(f / self.v.k_f)
        return omega_cmd, ControllerState(i_pos, i_att, e_w.clone())
