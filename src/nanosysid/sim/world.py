"""Nature: the effects of the simulated world that the nominal physics model lacks.

This is what makes the data, known only to the simulator and the oracle. Discovery never
imports it: its hypotheses are the separate library of :mod:`nanosysid.effects` (knowledge),
whose entries have other names and may have other forms. Each effect has a dimensionless strength: 1.0 is a realistic magnitude for the CF2.1
Brushless (numbers and sources in the docstrings), 0 switches it off. Effects that act on the
rigid body return an extra body-frame force and torque; ``telemetry_delay`` acts on the
recorded rotor speeds instead. Every function is batched over leading dimensions.

Rotor spin directions are :data:`nanosysid.dynamics.SPIN`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import torch
import torch.nn.functional as F
from torch import Tensor

from nanosysid import dynamics, so3
from nanosysid.vehicle import Vehicle

__all__ = ["EFFECTS", "World", "DEFAULT_WORLD"]

EFFECTS: dict[str, str] = {
    "rotor_drag": "blade flapping and induced drag: F_B = -(sum_i Omega_i) K v_B, K = diag(1.8e-6, 1.8e-6, 1.0e-6) kg/rad",
    "body_drag": "quadratic airframe drag: F_B = -c * |v_B| * v_B per axis, c = (1.5e-3, 1.5e-3, 3.0e-3) kg/m",
    "telemetry_delay": "the recorded rotor speeds lag the true ones by 30 ms (3 samples)",
    "com_offset": "centre of mass 1.5 mm forward and 1.0 mm right of the geometric centre: thrust torques roll/pitch",
    "motor_asymmetry": "per-rotor thrust (and drag-torque) coefficients k_F (1 + d_i), d = (+3.0, -2.0, +2.5, -3.5) %",
    "rotor_inertia": "rotor inertia J_r = 3.9e-8 kg m^2: yaw reaction -J_r sum s_i dOmega_i/dt and gyroscopic -w x h_rotors",
}

# Physical parameters at strength 1.0.
ROTOR_DRAG = (1.8e-6, 1.8e-6, 1.0e-6)  # kg/rad; Foerster's CF2 fit 0.92e-6, DM's CF21BL lumped drag 3.1e-6
BODY_DRAG = (1.5e-3, 1.5e-3, 3.0e-3)  # kg/m, 0.5 rho C_D A with about 25 cm^2 (side) and 50 cm^2 (top)
TELEMETRY_DELAY = 0.030  # s
COM_OFFSET = (1.5e-3, -1.0e-3, 0.0)  # m, within GRAFE's +-2 mm validation spread
MOTOR_ASYMMETRY = (0.030, -0.020, 0.025, -0.035)  # zero mean: the collective k_F is unchanged
ROTOR_INERTIA = 3.9e-8  # kg m^2, drone-models' cf21B propeller value


@dataclass(frozen=True, eq=False)
class World:
    """Strength of each effect; the ones not named are off."""

    strengths: Mapping[str, float]

    def __post_init__(self) -> None:
        unknown = set(self.strengths) - set(EFFECTS)
        if unknown:
            raise KeyError(f"unknown effects {sorted(unknown)}; known: {', '.join(EFFECTS)}")

    def s(self, name: str) -> float:
        return float(self.strengths.get(name, 0.0))

    @property
    def telemetry_delay(self) -> float:
        """Delay (s) of the recorded rotor speeds behind the true ones."""
        return self.s("telemetry_delay") * TELEMETRY_DELAY

    def _coeffs(self, dtype: torch.dtype, device, vehicle: Vehicle) -> dict[str, Tensor]:
        key = (dtype, device, vehicle)
        cache = self.__dict__.setdefault("_cache", {})
        if key not in cache:
            # constants of every active effect, built once: at a few flights per batch the
            # simulator's 1 kHz loop is bound by per-call overhead, not arithmetic
            def t(v):
                return torch.tensor(v, dtype=dtype, device=device)

            M = dynamics.mixer_matrix(k_f=vehicle.k_f, k_m=vehicle.k_m, arm=vehicle.arm, dtype=dtype, device=device)
            r = t(COM_OFFSET) * self.s("com_offset")
            cache[key] = {
                "rotor_drag": t(ROTOR_DRAG) * self.s("rotor_drag"),
                "body_drag": t(BODY_DRAG) * self.s("body_drag"),
                # torque of the thrust about the displaced centre of mass: -r x (0, 0, T) = T (-r_y, r_x, 0)
                "com_lever": torch.stack((-r[1], r[0], torch.zeros_like(r[0]))),
                # extra wrench of rotors with k_f (1 + d_i): linear in Omega^2, (4 wrench, 4 rotors)
                "asym": M * (t(MOTOR_ASYMMETRY) * self.s("motor_asymmetry")),
                "spin_jr": t(dynamics.SPIN) * ROTOR_INERTIA * self.s("rotor_inertia"),
            }
        return cache[key]

    def wrench(self, x: Tensor, omega: Tensor, omega_dot: Tensor, vehicle: Vehicle) -> tuple[Tensor, Tensor]:
        """Extra body-frame force ``(..., 3)`` (N) and torque ``(..., 3)`` (N m).

        Args:
            x: State ``(..., 13)``.
            omega: True rotor speeds ``(..., 4)`` (rad/s).
            omega_dot: Their time derivative ``(..., 4)`` (rad/s^2).
            vehicle: Nominal parameters (k_f, k_m, arm).
        """
        _, v, q, w = dynamics.split_state(x)
        c = self._coeffs(x.dtype, x.device, vehicle)
        force = torch.zeros_like(v)
        torque = torch.zeros_like(w)
        if self.s("rotor_drag") or self.s("body_drag"):
            v_b = so3.quat_rotate(so3.quat_conj(q), v)  # air velocity in the body frame (no wind)
            gain = omega.sum(-1, keepdim=True) * c["rotor_drag"] + c["body_drag"] * v_b.abs()
            force = force - gain * v_b
        om2 = omega * omega
        if self.s("com_offset"):
            torque = torque + (vehicle.k_f * om2.sum(-1, keepdim=True)) * c["com_lever"]
        if self.s("motor_asymmetry"):
            dw = om2 @ c["asym"].T  # (..., 4): extra thrust and torques
            force = force + F.pad(dw[..., :1], (2, 0))
            torque = torque + dw[..., 1:]
        if self.s("rotor_inertia"):
            h = (omega * c["spin_jr"]).sum(-1, keepdim=True)  # rotor angular momentum along body z
            yaw = -(omega_dot * c["spin_jr"]).sum(-1, keepdim=True)
            # -w x (0, 0, h) = (-w_y h, w_x h, 0), plus the reaction to spinning the rotors up
            torque = torque + torch.cat((-w[..., 1:2] * h, w[..., 0:1] * h, yaw), dim=-1)
        return force, torque


# The default world: every effect at a realistic magnitude, as on the real vehicle.
DEFAULT_WORLD: dict[str, float] = {name: 1.0 for name in EFFECTS}
