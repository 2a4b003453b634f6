"""Nature: the effects of the simulated world that the nominal physics model lacks.

This is what makes the data, known only to the simulator and the oracle. Discovery never
imports it: its hypotheses are the separate library of :mod:`nanosysid.effects` (knowledge),
whose entries have other names and may have other forms. Each effect has a dimensionless
strength: 1.0 is a realistic magnitude for the CF2.1 Brushless (numbers and sources beside the
constants below), 0 switches it off.

Most effects are functions of the state and the rotor speeds and act on the rigid body as an
extra body-frame force and torque. Two are not: ``telemetry_delay`` acts on the recorded rotor
speeds, and ``turbulence`` is a band-limited random force and torque, one realisation per
flight, drawn from the flight's seed (:meth:`World.disturbance`) so that the oracle can replay
it; no model of the state can know it. ``inertia_offset`` changes the rigid body itself.

:class:`Nature` is the wrench of a batch of flights, each with its own world, disturbance
realisation and user-supplied wrench (``extra_wrench``). Every function is batched over
leading dimensions. Rotor positions and spin directions are those of :mod:`nanosysid.dynamics`.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

import numpy as np
import torch
import torch.nn.functional as F
from scipy.signal import butter, lfilter
from torch import Tensor

from nanosysid import dynamics, so3
from nanosysid.vehicle import Vehicle

__all__ = ["EFFECTS", "DEPENDS_ON", "World", "Nature", "DEFAULT_WORLD", "ExtraWrench", "REALISATION_START"]

# fn(t (...,), x (..., 13), omega (..., 4), omega_dot (..., 4)) -> (force_B (..., 3), torque_B (..., 3))
ExtraWrench = Callable[[Tensor, Tensor, Tensor, Tensor], tuple[Tensor, Tensor]]

# What each effect is a function of: only the state-dependent ones can a model of the state learn.
DEPENDS_ON: dict[str, str] = {
    "rotor_drag": "state, rotor speeds",
    "body_drag": "state",
    "telemetry_delay": "the recorded rotor speeds' history",
    "com_offset": "rotor speeds",
    "motor_asymmetry": "rotor speeds",
    "rotor_inertia": "state, rotor speeds and their rates",
    "inertia_offset": "state, rotor speeds (the body's response)",
    "turbulence": "time: a new random realisation every flight",
    "unsteady_thrust": "time and rotor speeds: a new random realisation every flight",
}

# Physical parameters at strength 1.0.
ROTOR_DRAG = (1.8e-6, 1.8e-6, 1.0e-6)  # kg/rad; Foerster's CF2 fit 0.92e-6, DM's CF21BL lumped drag 3.1e-6
# m: the propeller plane above the centre of mass (motor can and propeller hub over the board,
# the battery and decks near the board; estimated from the layout, no measurement known)
ROTOR_HUB_HEIGHT = 0.008
BODY_DRAG = (1.5e-3, 1.5e-3, 3.0e-3)  # kg/m, 0.5 rho C_D A with about 25 cm^2 (side) and 50 cm^2 (top)
TELEMETRY_DELAY = 0.030  # s
COM_OFFSET = (1.5e-3, -1.0e-3, 0.0)  # m, within GRAFE's +-2 mm validation spread
MOTOR_ASYMMETRY = (0.030, -0.020, 0.025, -0.035)  # zero mean: the collective k_F is unchanged
ROTOR_INERTIA = 3.9e-8  # kg m^2, drone-models' cf21B propeller value
# relative error of the nominal inertia (the paper's 2.40, 2.40, 3.23 e-5 kg m^2): drone-models'
# fit is (2.5, 2.8, 4.9) e-5 and GRAFE's (3.3, 3.6, 5.9) e-5 for the same airframe class
INERTIA_OFFSET = (0.15, 0.15, 0.25)
# Band-limited disturbance: the paper's unexplained slow roll/pitch torque and the force that the
# residual networks cannot learn; its size is set so that the physics row matches the paper's
# (reports/sim/stats.md), a few per cent of the hover thrust and of the rotors' roll/pitch authority
TURBULENCE_FORCE = (5.0e-3, 5.0e-3, 6.0e-3)  # N, std per body axis
TURBULENCE_TORQUE = (2.5e-4, 2.5e-4, 0.4e-4)  # N m, std per body axis
TURBULENCE_BAND = 1.0  # Hz, corner of the second-order low-pass
# The paper's "unmodelled actuation": the thrust a rotor gives at a measured speed is not a fixed
# k_F Omega^2; the controller answers the fluctuation with the rotor speeds, so the measured speeds
# tell less of the torque than the quadratic model says. Its size, like the turbulence's, is set
# by the physics and Phys+Res rows of the paper (reports/sim/stats.md).
UNSTEADY_THRUST = 0.045  # std of each rotor's relative thrust and drag-torque fluctuation
UNSTEADY_THRUST_BAND = 3.0  # Hz

def _mm(v) -> str:
    return ", ".join(f"{x * 1e3:g}" for x in v)


EFFECTS: dict[str, str] = {
    "rotor_drag": f"blade flapping and induced drag of each rotor from its own air velocity v_i = v_B + w x r_i, at the "
                  f"rotor hub {ROTOR_HUB_HEIGHT * 1e3:g} mm above the centre of mass: F_i = -Omega_i K v_i, "
                  f"K = diag{ROTOR_DRAG} kg/rad (the z part: thrust falling with the rotor's axial inflow); "
                  "torque sum r_i x F_i",
    "body_drag": f"quadratic airframe drag: F_B = -c * |v_B| * v_B per axis, c = {BODY_DRAG} kg/m",
    "telemetry_delay": f"the recorded rotor speeds lag the true ones by {TELEMETRY_DELAY * 1e3:g} ms",
    "com_offset": f"centre of mass at ({_mm(COM_OFFSET)}) mm from the geometric centre: thrust torques roll/pitch",
    "motor_asymmetry": "per-rotor thrust (and drag-torque) coefficients k_F (1 + d_i), "
                       f"d = ({', '.join(f'{d * 100:+g}' for d in MOTOR_ASYMMETRY)}) %",
    "rotor_inertia": f"rotor inertia J_r = {ROTOR_INERTIA:g} kg m^2: yaw reaction -J_r sum s_i dOmega_i/dt and "
                     "gyroscopic -w x h_rotors",
    "inertia_offset": f"the body's inertia is ({', '.join(f'{d * 100:+g}' for d in INERTIA_OFFSET)}) % off the nominal "
                      "diagonal",
    "turbulence": f"band-limited random body force and torque (downwash recirculating in the arena): std "
                  f"({_mm(TURBULENCE_FORCE)}) mN and ({', '.join(f'{x:g}' for x in TURBULENCE_TORQUE)}) N m, "
                  f"low-pass {TURBULENCE_BAND:g} Hz; a new realisation every flight",
    "unsteady_thrust": "each rotor's thrust and drag torque fluctuate around k Omega^2 (unsteady aerodynamics of the "
                       f"rotor in its own disturbed inflow): factors 1 + e_i(t), e_i of std {UNSTEADY_THRUST:.1%}, "
                       f"low-pass {UNSTEADY_THRUST_BAND:g} Hz, independent per rotor; a new realisation every flight",
}

# w @ _GYRO = (-w_y, w_x, 0)
_GYRO = torch.tensor([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]], dtype=torch.float64)

# Realisations of time-varying effects are drawn on a fixed grid from a fixed start, so that a
# value depends only on the flight's seed and the time, however long the flight.
REALISATION_RATE = 100.0  # Hz
REALISATION_START = -30.0  # s before the trajectory starts (the simulator's pre-roll must be shorter)


def _unit_band_noise(key: Sequence[int], t_end: float, channels: int, band: float) -> np.ndarray:
    """``(N, channels)`` samples on the realisation grid up to ``t_end``: white noise through a
    second-order Butterworth low-pass at ``band`` Hz, scaled to unit stationary std."""
    n = int(np.ceil((t_end - REALISATION_START) * REALISATION_RATE)) + 2
    b, a = butter(2, band / (REALISATION_RATE / 2))
    impulse = lfilter(b, a, np.r_[1.0, np.zeros(20 * int(np.ceil(REALISATION_RATE / band)))])
    white = np.random.default_rng(list(key)).standard_normal((n, channels))
    return lfilter(b, a, white, axis=0) / np.sqrt(np.sum(impulse**2))


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

    def inertia(self, vehicle: Vehicle) -> tuple[float, float, float]:
        """The body's true inertia diagonal (kg m^2)."""
        k = self.s("inertia_offset")
        return tuple(j * (1 + k * d) for j, d in zip(vehicle.inertia, INERTIA_OFFSET))

    def disturbance(self, key: Sequence[int], t_end: float) -> np.ndarray | None:
        """The flight's time-varying effects on the realisation grid (:data:`REALISATION_START` +
        n / :data:`REALISATION_RATE`) up to ``t_end`` s, ``(N, 10)``: the turbulence's body force
        (N) and torque (N m), and each rotor's relative thrust fluctuation; None when both are
        off. ``key`` (whole numbers) identifies the flight; the same key gives the same
        realisation, each effect from its own stream."""
        if not (self.s("turbulence") or self.s("unsteady_thrust")):
            return None
        out = np.zeros((int(np.ceil((t_end - REALISATION_START) * REALISATION_RATE)) + 2, 10))
        if self.s("turbulence"):
            scale = self.s("turbulence") * np.array([*TURBULENCE_FORCE, *TURBULENCE_TORQUE])
            out[:, :6] = _unit_band_noise([*key, 1], t_end, 6, TURBULENCE_BAND) * scale
        if self.s("unsteady_thrust"):
            scale = self.s("unsteady_thrust") * UNSTEADY_THRUST
            out[:, 6:] = _unit_band_noise([*key, 2], t_end, 4, UNSTEADY_THRUST_BAND) * scale
        return out

    def wrench(self, x: Tensor, omega: Tensor, omega_dot: Tensor, vehicle: Vehicle) -> tuple[Tensor, Tensor]:
        """Extra body-frame force ``(..., 3)`` (N) and torque ``(..., 3)`` (N m) of the effects that
        are functions of the state and the rotor speeds (no turbulence: see :class:`Nature`).

        Args:
            x: State ``(..., 13)``.
            omega: True rotor speeds ``(..., 4)`` (rad/s).
            omega_dot: Their time derivative ``(..., 4)`` (rad/s^2).
            vehicle: Nominal parameters (k_f, k_m, arm).
        """
        return Nature([self], vehicle, dtype=x.dtype).wrench(None, x, omega, omega_dot)


def _extra_groups(extra: Sequence[ExtraWrench | None], dtype) -> list[tuple[ExtraWrench, Tensor, dict[str, Tensor]]]:
    """The flights' user-supplied wrenches as calls: one per function, and one per family of
    ``functools.partial`` s of one function with numeric keywords (the keywords stacked per
    flight), so that a thousand worlds of one effect at a thousand strengths cost one call."""
    groups: dict[tuple, list[int]] = {}
    for i, fn in enumerate(extra):
        if fn is None:
            continue
        key: tuple = (fn, ())
        if isinstance(fn, functools.partial) and not fn.args and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in fn.keywords.values()):
            key = (fn.func, tuple(sorted(fn.keywords)))
        groups.setdefault(key, []).append(i)
    return [(fn, torch.tensor(rows), {k: torch.tensor([extra[i].keywords[k] for i in rows], dtype=dtype) for k in names})
            for (fn, names), rows in groups.items()]


class Nature:
    """The extra wrench of a batch of flights, each with its own world.

    Args:
        worlds: One world per flight, or one for all (the leading dimension of the states then
            broadcasts).
        vehicle: Nominal parameters.
        disturbances: Per flight, the realisation of :meth:`World.disturbance` (or None).
        extra: Per flight (or one for all), a user-supplied ``fn(t, x, omega, omega_dot) ->
            (force_B, torque_B)`` in SI units, or None. Flights whose functions are
            ``functools.partial(f, k=number, ...)`` of one ``f`` are evaluated in one call, each
            keyword a tensor ``(flights, 1, ...)`` of the flights' values.
    """

    def __init__(self, worlds: Sequence[World], vehicle: Vehicle, *, disturbances: Sequence[np.ndarray | None] = (),
                 extra: Sequence[ExtraWrench | None] | ExtraWrench | None = None, dtype=torch.float64) -> None:
        self.B = len(worlds)
        self.vehicle = vehicle

        def stack(values) -> Tensor:  # (B, k)
            return torch.tensor([list(v) for v in values], dtype=dtype)

        def on(name: str) -> bool:
            return any(w.s(name) for w in worlds)

        s = {name: torch.tensor([[w.s(name)] for w in worlds], dtype=dtype) for name in EFFECTS}
        M = dynamics.mixer_matrix(k_f=vehicle.k_f, k_m=vehicle.k_m, arm=vehicle.arm, dtype=dtype)
        # Constants of the active effects, one row per flight, built once; the effects that are
        # linear in Omega^2 or dOmega/dt are gathered into one matrix each: the simulator's loop
        # is bound by the number of tensor operations, not by arithmetic.
        c: dict[str, Tensor] = {}
        per_om2 = torch.zeros(self.B, 4, 6, dtype=dtype)  # wrench [F (3), tau (3)] per Omega_i^2
        if on("com_offset"):
            off = s["com_offset"] * torch.tensor(COM_OFFSET, dtype=dtype)
            # torque of the thrust about the displaced centre of mass: -r x (0, 0, T) = T (-r_y, r_x, 0)
            per_om2[:, :, 3] += -vehicle.k_f * off[:, 1:2]
            per_om2[:, :, 4] += vehicle.k_f * off[:, 0:1]
        if on("motor_asymmetry"):
            # rotors with k_f (1 + d_i): extra thrust and torques linear in Omega_i^2
            spread = (M * torch.tensor(MOTOR_ASYMMETRY, dtype=dtype)).T  # (4 rotors, [T, tau])
            per_om2[:, :, 2] += s["motor_asymmetry"] * spread[:, 0]
            per_om2[:, :, 3:] += s["motor_asymmetry"].unsqueeze(-1) * spread[:, 1:]
        if on("com_offset") or on("motor_asymmetry"):
            c["per_om2"] = per_om2
        if on("rotor_inertia"):
            spin_jr = s["rotor_inertia"] * torch.tensor(dynamics.SPIN, dtype=dtype) * ROTOR_INERTIA  # (B, 4)
            c["spin_jr"] = spin_jr
            # the reaction to spinning the rotors up: tau_z = -J_r sum s_i dOmega_i/dt
            c["per_om_dot"] = F.pad(-spin_jr.unsqueeze(-1), (5, 0))  # (B, 4, 6)
        if on("rotor_drag"):
            K = s["rotor_drag"] * torch.tensor(ROTOR_DRAG, dtype=dtype)  # (B, 3)
            r = torch.tensor([[xs * vehicle.arm, ys * vehicle.arm, ROTOR_HUB_HEIGHT]
                              for xs, ys in zip(dynamics.ROTOR_X, dynamics.ROTOR_Y)], dtype=dtype)  # (4, 3) hubs
            # F_i = -Omega_i K (v_B + w x r_i) sums to -K (sum_i Omega_i v_B + w x rho), rho = sum_i Omega_i r_i;
            # sum_i r_i x F_i = -rho x (K v_B) + sum_i Omega_i [r_i]x K [r_i]x w
            rx = torch.zeros(4, 3, 3, dtype=dtype)
            rx[:, 0, 1], rx[:, 0, 2], rx[:, 1, 2] = -r[:, 2], r[:, 1], -r[:, 0]
            rx = rx - rx.transpose(-1, -2)
            c["drag_K"] = K
            c["hub"] = r.unsqueeze(0).expand(self.B, 4, 3)
            c["drag_rot"] = (rx.unsqueeze(0) @ torch.diag_embed(K).unsqueeze(1) @ rx.unsqueeze(0)).flatten(-2)  # (B, 4, 9)
        if on("body_drag"):
            c["body_drag"] = s["body_drag"] * torch.tensor(BODY_DRAG, dtype=dtype)
        self.c = c
        self.mixer_t = M.T
        self.unsteady = on("unsteady_thrust")
        self.inertia = None
        if on("inertia_offset"):
            self.inertia = stack(w.inertia(vehicle) for w in worlds)  # (B, 3)
        self.table = None
        if any(d is not None for d in disturbances):
            n = max(len(d) for d in disturbances if d is not None)
            table = np.zeros((self.B, n, 10))
            for i, d in enumerate(disturbances):
                if d is not None:
                    table[i, :len(d)] = d
                    table[i, len(d):] = d[-1]
            self.table = torch.from_numpy(table).to(dtype)
        if extra is None or callable(extra):
            self.extra = extra
        else:
            self.extra = list(extra) if any(fn is not None for fn in extra) else None
            self.groups = _extra_groups(self.extra, dtype) if self.extra is not None else []
        self.active = bool(c) or self.table is not None or self.extra is not None

    @property
    def timed(self) -> bool:
        """Whether the wrench depends on time (turbulence or a user-supplied wrench)."""
        return self.table is not None or self.extra is not None

    def _per_flight(self, v: Tensor, x: Tensor) -> Tensor:
        """``(B, *k)`` constants shaped to broadcast against ``x (B, ..., 13)``."""
        return v.view(v.shape[0], *([1] * (x.dim() - 2)), *v.shape[1:]) if x.dim() > 2 else v

    def _constants(self, x: Tensor) -> dict[str, Tensor]:
        key = (x.dim(), x.dtype)
        cache = self.__dict__.setdefault("_shaped", {})
        if key not in cache:
            cache[key] = {k: self._per_flight(v.to(x.dtype), x) for k, v in self.c.items()}
        return cache[key]

    def body_inertia(self, x: Tensor) -> Tensor | None:
        """The true inertia diagonal shaped for ``x``, or None where it is the nominal one."""
        return None if self.inertia is None else self._per_flight(self.inertia.to(x.dtype), x)

    def _disturbance(self, t, x: Tensor) -> Tensor:
        """The realisation ``(..., 10)`` at time ``t`` (a float, or a tensor of ``x``'s leading shape)."""
        pos = (t - REALISATION_START) * REALISATION_RATE
        n = self.table.shape[1]
        if not torch.is_tensor(t):
            i0 = min(max(int(np.floor(pos)), 0), n - 2)
            v = torch.lerp(self.table[:, i0], self.table[:, i0 + 1], min(max(pos - i0, 0.0), 1.0))  # (B, 6)
            return self._per_flight(v, x) if x.dim() > 2 else v
        i0 = pos.floor().clamp(0, n - 2)
        w = (pos - i0).clamp(0, 1).unsqueeze(-1)
        i0 = i0.long()
        if self.table.shape[0] == 1:
            lo, hi = self.table[0][i0], self.table[0][i0 + 1]
        else:
            b = torch.arange(self.table.shape[0]).view(-1, *([1] * (i0.dim() - 1))).expand_as(i0)
            lo, hi = self.table[b, i0], self.table[b, i0 + 1]
        return lo * (1 - w) + hi * w

    def _extra(self, t, x: Tensor, omega: Tensor, omega_dot: Tensor) -> tuple[Tensor, Tensor]:
        tt = t if torch.is_tensor(t) else torch.full(x.shape[:-1], float(t), dtype=x.dtype)
        if callable(self.extra):
            return self.extra(tt, x, omega, omega_dot)
        force, torque = torch.zeros_like(x[..., :3]), torch.zeros_like(x[..., :3])
        per_flight = (-1,) + (1,) * (x.dim() - 2)
        for fn, rows, keywords in self.groups:
            kw = {k: v.view(per_flight) for k, v in keywords.items()}
            f, tq = fn(tt[rows], x[rows], omega[rows], omega_dot[rows], **kw)
            force.index_add_(0, rows, f)
            torque.index_add_(0, rows, tq)
        return force, torque

    def wrench(self, t, x: Tensor, omega: Tensor, omega_dot: Tensor) -> tuple[Tensor, Tensor]:
        """Extra body-frame force ``(..., 3)`` (N) and torque ``(..., 3)`` (N m).

        Args:
            t: Time (s) from the start of the trajectory: a float, or a tensor of the states'
                leading shape; None when no effect depends on time.
            x: State ``(B, ..., 13)``.
            omega: True rotor speeds ``(B, ..., 4)`` (rad/s).
            omega_dot: Their time derivative ``(B, ..., 4)`` (rad/s^2).
        """
        _, v, q, w = dynamics.split_state(x)
        c = self._constants(x)
        wrench = None  # (..., 6): force, torque

        def add(w6):
            return w6 if wrench is None else wrench + w6

        if "per_om2" in c:
            wrench = add((omega * omega).unsqueeze(-1).mul(c["per_om2"]).sum(-2))
        if "spin_jr" in c:
            wrench = add(omega_dot.unsqueeze(-1).mul(c["per_om_dot"]).sum(-2))
            h = (omega * c["spin_jr"]).sum(-1, keepdim=True)  # rotor angular momentum along body z
            # gyroscopic torque -w x (0, 0, h) = h (-w_y, w_x, 0)
            wrench = wrench + F.pad(h * (w @ _GYRO.to(w.dtype)), (3, 0))
        if "drag_K" in c or "body_drag" in c:
            v_b = so3.quat_rotate(so3.quat_conj(q), v)  # air velocity in the body frame (no wind)
            if "drag_K" in c:
                K = c["drag_K"]
                rho = (omega.unsqueeze(-1) * c["hub"]).sum(-2)  # sum_i Omega_i r_i
                Kv = K * v_b
                force = -(omega.sum(-1, keepdim=True) * Kv + K * torch.linalg.cross(w, rho, dim=-1))
                rot = (omega.unsqueeze(-1) * c["drag_rot"]).sum(-2).unflatten(-1, (3, 3))
                torque = (rot @ w.unsqueeze(-1)).squeeze(-1) - torch.linalg.cross(rho, Kv, dim=-1)
                wrench = add(torch.cat((force, torque), -1))
            if "body_drag" in c:
                wrench = add(F.pad(-c["body_drag"] * v_b.abs() * v_b, (0, 3)))
        if self.table is not None:
            d = self._disturbance(t, x)
            wrench = add(d[..., :6])
            if self.unsteady:
                # thrust and drag torque of rotors whose k_F and k_M are (1 + e_i) times the nominal
                wrench = wrench + F.pad((d[..., 6:] * omega * omega) @ self.mixer_t, (2, 0))
        if wrench is None:
            wrench = torch.zeros_like(x[..., :6])
        force, torque = wrench[..., :3], wrench[..., 3:]
        if self.extra is not None:
            f, tq = self._extra(t, x, omega, omega_dot)
            force, torque = force + f, torque + tq
        return force, torque


# The default world: the effects the real vehicle has, at realistic magnitudes, chosen so that
# the benchmark's results show the pattern of the paper's real flights (reports/sim/stats.md).
# The centre-of-mass offset and the rotor spread are the constant roll/pitch torques a learned
# residual picks up; at their full size the learned models beat physics on the orientation,
# which the paper's do not.
DEFAULT_WORLD: dict[str, float] = {
    "rotor_drag": 1.0,
    "body_drag": 1.0,
    "telemetry_delay": 1.0,
    "com_offset": 0.3,
    "motor_asymmetry": 0.5,
    "rotor_inertia": 1.0,
    "turbulence": 1.0,
    "unsteady_thrust": 1.0,
}
