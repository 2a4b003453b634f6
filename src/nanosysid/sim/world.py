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

__all__ = ["WorldEffect", "Realisation", "Body", "RECORDS", "REGISTRY", "register", "unregister", "state_effects",
           "EFFECTS", "DEPENDS_ON", "World", "Nature", "DEFAULT_WORLD", "ExtraWrench", "REALISATION_START"]

# fn(t (...,), x (..., 13), omega (..., 4), omega_dot (..., 4)) -> (force_B (..., 3), torque_B (..., 3))
ExtraWrench = Callable[[Tensor, Tensor, Tensor, Tensor], tuple[Tensor, Tensor]]

# Physical parameters at strength 1.0, with their sources; each effect's record below uses them.
# kg/rad; Foerster's CF2 fit 0.92e-6, DM's CF21BL lumped drag 3.1e-6; in x and y the rig's own
# (its induced drag K_xy, 2.67e-6 to 2.91e-6 over its flights: reports/rig/discovery); in z the
# rig's thrust residual against its climb rate reads 2.3e-6 to 3.0e-6 per trajectory, where the
# same regression reads 2.5e-6 to 2.8e-6 on this world (its body drag and the filters add to K_z;
# reports/rig/world.md, 'The thrust residual and the climb rate')
ROTOR_DRAG = (2.8e-6, 2.8e-6, 2.0e-6)
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
# residual networks cannot learn; the force's size is set so that the physics row matches the
# paper's (reports/sim/stats.md), a few per cent of the hover thrust; the torque's size and band
# per axis are the rig's torque residual's (reports/rig/world.md): its pitch residual is larger
# than its roll residual, and its yaw residual sits higher
TURBULENCE_FORCE = (4.0e-3, 4.0e-3, 4.8e-3)  # N, std per body axis
TURBULENCE_TORQUE = (4.5e-4, 7.0e-4, 0.3e-4)  # N m, std per body axis
TURBULENCE_BAND = 1.0  # Hz, corner of the second-order low-pass of the force
# Hz, the torque's corners: the rig's roll and pitch residual sits at 0.3-0.4 Hz (its median
# frequency), where the attitude loop cancels it through the rotor speeds; its yaw residual at 2-3 Hz
TURBULENCE_TORQUE_BAND = (0.4, 0.4, 3.0)
# Gusts: the arena's air in steps rather than as a smooth turbulence (a door, a fan, the
# downwash off a wall the vehicle passes): a body force and roll/pitch torque that hold a random
# level for a random time (exponential, mean GUST_DWELL) and move to the next within GUST_RISE.
# Their spectrum falls as 1/f² above 1 / (pi GUST_DWELL) and their edges are sharp, a shape and
# spectrum the turbulence's record has not; off in the default world (the worlds check's family)
GUST_FORCE = (4.0e-3, 4.0e-3, 0.0)  # N, std per body axis
GUST_TORQUE = (4.0e-4, 4.0e-4, 0.0)  # N m, std per body axis
GUST_DWELL = 2.0  # s
GUST_RISE = 0.1  # s
# The paper's "unmodelled actuation": the thrust a rotor gives at a measured speed is not a fixed
# k_F Omega^2; the controller answers the fluctuation with the rotor speeds, so the measured speeds
# tell less of the torque than the quadratic model says. Its size, like the turbulence's, is set
# by the physics and Phys+Res rows of the paper (reports/sim/stats.md); the default world flies it
# at 0.6 of that: with the rig's climb drag carrying the slow part of the thrust residual, the
# fluctuation at 0.6 leaves the yaw residual's median frequency at the rig's (reports/rig/world.md)
UNSTEADY_THRUST = 0.045  # std of each rotor's relative thrust and drag-torque fluctuation
UNSTEADY_THRUST_BAND = 3.0  # Hz
# The paper's hypothesis for the same torque, as a function of the rotor speeds' history: a share
# of each rotor's thrust and drag torque follows k Omega^2 through a slow first-order lag
SLOW_ACTUATION = 0.25  # share of the rotor's wrench that lags, at strength 1 (at most MAX_SLOW_SHARE)
SLOW_ACTUATION_TIME = 0.3  # s, the lag's time constant
# With more than half the wrench 0.3 s behind the rotors, the vehicle's controller (which, like the
# rig's, takes the thrust for the rotors' at once) no longer flies the trajectories: the Square
# and the Melon diverge at a share of 0.6
MAX_SLOW_SHARE = 0.5

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


def _unit_steps(key: Sequence[int], t_end: float, channels: int, rate: float) -> np.ndarray:
    """``(N, channels)`` samples on the realisation grid up to ``t_end``: each channel holds a
    standard normal level for an exponential time of mean ``1 / rate`` s, then steps to the next
    through a first-order lag of :data:`GUST_RISE` s. Each channel draws (time held, next level)
    pairs from its own stream in blocks, so a longer flight's realisation begins with a shorter
    one's."""
    n = int(np.ceil((t_end - REALISATION_START) * REALISATION_RATE)) + 2
    out = np.empty((n, channels))
    for c in range(channels):
        rng = np.random.default_rng([*key, c])
        first, held, levels, total = rng.standard_normal(), [], [], 0.0
        while total < n:
            held.append(rng.exponential(REALISATION_RATE / rate, 64))  # samples each level holds
            levels.append(rng.standard_normal(64))
            total += held[-1].sum()
        ends = np.cumsum(np.concatenate(held))
        out[:, c] = np.r_[first, np.concatenate(levels)][np.searchsorted(ends, np.arange(n), side="right")]
    return _lowpass(out, 1.0 / REALISATION_RATE, GUST_RISE)


def _lowpass(x: np.ndarray, dt: float, tau: float) -> np.ndarray:
    """First-order low-pass of time constant ``tau`` (s) along axis -2 of ``x (..., T, k)``
    sampled every ``dt`` s, at rest at the first sample."""
    a = 1.0 - np.exp(-dt / tau)
    return lfilter([a], [1.0, a - 1.0], x, axis=-2, zi=(1.0 - a) * x[..., :1, :])[0]


def _mm(v) -> str:
    return ", ".join(f"{x * 1e3:g}" for x in v)


class Body:
    """The state ``(..., 13)`` of a batch, split once for every effect's wrench; the body-frame
    air velocity (no wind) is computed on first use."""

    __slots__ = ("x", "v", "q", "w", "_v_b")

    def __init__(self, x: Tensor) -> None:
        self.x = x
        _, self.v, self.q, self.w = dynamics.split_state(x)
        self._v_b = None

    @property
    def v_b(self) -> Tensor:
        if self._v_b is None:
            self._v_b = so3.quat_rotate(so3.quat_conj(self.q), self.v)
        return self._v_b


@dataclass(frozen=True)
class Realisation:
    """A time-varying effect: band-limited random channels, one realisation per flight.

    Attributes:
        scale: Standard deviation of each channel at strength 1.0.
        band: Corner (Hz) of the second-order low-pass, one for all channels or one per channel.
        stream: Index of its random stream within the flight's key (each effect its own).
        apply: ``(channels (..., k), omega (..., 4), mixer_t (4, 4)) -> wrench (..., 6)``.
        draw: ``(key, t_end, channels, band) -> (N, channels)`` unit-std samples on the
            realisation grid: band-limited noise, or steps (``band`` their rate, 1/s).
    """

    scale: tuple[float, ...]
    band: float | tuple[float, ...]
    stream: int
    apply: Callable[[Tensor, Tensor, Tensor], Tensor]
    draw: Callable[[Sequence[int], float, int, float], np.ndarray] = _unit_band_noise


@dataclass(frozen=True)
class WorldEffect:
    """One effect of nature: what it is, what it depends on, its strength in the default world,
    the library entries that describe it, and its wrench at a strength ``s`` (a ``(B, 1)``
    tensor, one row per flight).

    The wrench comes in up to three parts: a matrix ``(B, 4, 6)`` of body force and torque per
    Omega_i^2 (``per_omega2``), one per dOmega_i/dt (``per_omega_rate``), and any other function
    (``wrench``, from the per-flight constants that ``prepare`` builds once). Nature gathers the
    matrices of all effects into one each and sums the parts in the order of :data:`RECORDS`:
    the simulator's loop is bound by the number of tensor operations, not by arithmetic.
    ``telemetry_delay`` and ``inertia_offset`` have no wrench: the simulator applies them to the
    recorded rotor speeds and to the rigid body.

    Attributes:
        name: The key of ``sim.effects``.
        summary: What it does, in a phrase (the README's world table).
        description: What it does, with its magnitudes at strength 1.0.
        depends_on: What it is a function of: only the state-dependent ones can a model of the
            state learn.
        default: Its strength in the default world.
        described_by: The library entries (:mod:`nanosysid.effects`) that describe it, in any of
            their forms: the judge's table, fixed before any discovery runs.
        truth: The library entry that describes it one to one, and that entry's coefficients at
            a strength: ``(entry, fn(s, vehicle) -> values)``; None where none does.
        realisation: Its random channels, for an effect of time.
    """

    name: str
    summary: str
    description: str
    depends_on: str
    default: float = 0.0
    described_by: frozenset[str] = frozenset()
    truth: tuple[str, Callable[[float, Vehicle], list[float]]] | None = None
    per_omega2: Callable[[Tensor, Vehicle, torch.dtype], Tensor] | None = None
    per_omega_rate: Callable[[Tensor, Vehicle, torch.dtype], Tensor] | None = None
    prepare: Callable[[Tensor, Vehicle, torch.dtype], dict[str, Tensor]] | None = None
    wrench: Callable[[Mapping[str, Tensor], Body, Tensor, Tensor], Tensor] | None = None
    realisation: Realisation | None = None

    @property
    def time_varying(self) -> bool:
        """Whether it is a new random realisation every flight (no model of the state can know it)."""
        return self.realisation is not None


def _com_offset_per_omega2(s: Tensor, vehicle: Vehicle, dtype) -> Tensor:
    off = s * torch.tensor(COM_OFFSET, dtype=dtype)
    out = torch.zeros(len(s), 4, 6, dtype=dtype)
    # torque of the thrust about the displaced centre of mass: -r x (0, 0, T) = T (-r_y, r_x, 0)
    out[:, :, 3] += -vehicle.k_f * off[:, 1:2]
    out[:, :, 4] += vehicle.k_f * off[:, 0:1]
    return out


def _mixer(vehicle: Vehicle, dtype) -> Tensor:
    return dynamics.mixer_matrix(k_f=vehicle.k_f, k_m=vehicle.k_m, arm=vehicle.arm, dtype=dtype)


def _asymmetry_per_omega2(s: Tensor, vehicle: Vehicle, dtype) -> Tensor:
    # rotors with k_f (1 + d_i): extra thrust and torques linear in Omega_i^2
    spread = (_mixer(vehicle, dtype) * torch.tensor(MOTOR_ASYMMETRY, dtype=dtype)).T  # (4 rotors, [T, tau])
    out = torch.zeros(len(s), 4, 6, dtype=dtype)
    out[:, :, 2] += s * spread[:, 0]
    out[:, :, 3:] += s.unsqueeze(-1) * spread[:, 1:]
    return out


def _spin_jr(s: Tensor, dtype) -> Tensor:
    return s * torch.tensor(dynamics.SPIN, dtype=dtype) * ROTOR_INERTIA  # (B, 4)


def _rotor_inertia_per_rate(s: Tensor, vehicle: Vehicle, dtype) -> Tensor:
    # the reaction to spinning the rotors up: tau_z = -J_r sum s_i dOmega_i/dt
    return F.pad(-_spin_jr(s, dtype).unsqueeze(-1), (5, 0))  # (B, 4, 6)


def _rotor_inertia_wrench(c: Mapping[str, Tensor], body: Body, omega: Tensor, omega_dot: Tensor) -> Tensor:
    h = (omega * c["spin_jr"]).sum(-1, keepdim=True)  # rotor angular momentum along body z
    # gyroscopic torque -w x (0, 0, h) = h (-w_y, w_x, 0)
    return F.pad(h * (body.w @ _GYRO.to(body.w.dtype)), (3, 0))


def _rotor_drag_constants(s: Tensor, vehicle: Vehicle, dtype) -> dict[str, Tensor]:
    K = s * torch.tensor(ROTOR_DRAG, dtype=dtype)  # (B, 3)
    r = torch.tensor([[xs * vehicle.arm, ys * vehicle.arm, ROTOR_HUB_HEIGHT]
                      for xs, ys in zip(dynamics.ROTOR_X, dynamics.ROTOR_Y)], dtype=dtype)  # (4, 3) hubs
    # F_i = -Omega_i K (v_B + w x r_i) sums to -K (sum_i Omega_i v_B + w x rho), rho = sum_i Omega_i r_i;
    # sum_i r_i x F_i = -rho x (K v_B) + sum_i Omega_i [r_i]x K [r_i]x w
    rx = torch.zeros(4, 3, 3, dtype=dtype)
    rx[:, 0, 1], rx[:, 0, 2], rx[:, 1, 2] = -r[:, 2], r[:, 1], -r[:, 0]
    rx = rx - rx.transpose(-1, -2)
    return {"K": K, "hub": r.unsqueeze(0).expand(len(s), 4, 3),
            "rot": (rx.unsqueeze(0) @ torch.diag_embed(K).unsqueeze(1) @ rx.unsqueeze(0)).flatten(-2)}  # (B, 4, 9)


def _rotor_drag_wrench(c: Mapping[str, Tensor], body: Body, omega: Tensor, omega_dot: Tensor) -> Tensor:
    K, w = c["K"], body.w
    rho = (omega.unsqueeze(-1) * c["hub"]).sum(-2)  # sum_i Omega_i r_i
    Kv = K * body.v_b
    force = -(omega.sum(-1, keepdim=True) * Kv + K * torch.linalg.cross(w, rho, dim=-1))
    rot = (omega.unsqueeze(-1) * c["rot"]).sum(-2).unflatten(-1, (3, 3))
    torque = (rot @ w.unsqueeze(-1)).squeeze(-1) - torch.linalg.cross(rho, Kv, dim=-1)
    return torch.cat((force, torque), -1)


def _body_drag_wrench(c: Mapping[str, Tensor], body: Body, omega: Tensor, omega_dot: Tensor) -> Tensor:
    v_b = body.v_b
    return F.pad(-c["c"] * v_b.abs() * v_b, (0, 3))


def _unsteady_wrench(d: Tensor, omega: Tensor, mixer_t: Tensor) -> Tensor:
    # thrust and drag torque of rotors whose k_F and k_M are (1 + e_i) times the nominal
    return F.pad((d * omega * omega) @ mixer_t, (2, 0))


# The effects of nature. Their order is the order in which their wrenches are summed (after the
# gathered matrices), which fixes the simulator's bytes. The default strengths are the mix that
# makes the benchmark's results show the pattern of the paper's real flights
# (reports/sim/stats.md): the centre-of-mass offset and the rotor spread are the constant
# roll/pitch torques a learned residual picks up; at their full size the learned models beat
# physics on the orientation, which the paper's do not.
RECORDS: tuple[WorldEffect, ...] = (
    WorldEffect(
        "com_offset", "centre of mass off the geometric centre: thrust torques roll and pitch",
        f"centre of mass at ({_mm(COM_OFFSET)}) mm from the geometric centre: thrust torques roll/pitch",
        "rotor speeds", default=0.3, described_by=frozenset({"cg_offset"}),
        truth=("cg_offset", lambda s, vehicle: [s * COM_OFFSET[0], s * COM_OFFSET[1]]),
        per_omega2=_com_offset_per_omega2),
    WorldEffect(
        "motor_asymmetry", "per-rotor thrust coefficients a few percent apart",
        "per-rotor thrust (and drag-torque) coefficients k_F (1 + d_i), "
        f"d = ({', '.join(f'{d * 100:+g}' for d in MOTOR_ASYMMETRY)}) %",
        "rotor speeds", default=0.5, described_by=frozenset({"rotor_spread"}),
        truth=("rotor_spread", lambda s, vehicle: [s * d for d in MOTOR_ASYMMETRY]),
        per_omega2=_asymmetry_per_omega2),
    WorldEffect(
        "rotor_inertia", "yaw torque from rotor acceleration and gyroscopic torque of the spinning rotors",
        f"rotor inertia J_r = {ROTOR_INERTIA:g} kg m^2: yaw reaction -J_r sum s_i dOmega_i/dt and gyroscopic "
        "-w x h_rotors",
        "state, rotor speeds and their rates", default=1.0, described_by=frozenset({"rotor_gyro"}),
        truth=("rotor_gyro", lambda s, vehicle: [s * ROTOR_INERTIA]),
        per_omega_rate=_rotor_inertia_per_rate,
        prepare=lambda s, vehicle, dtype: {"spin_jr": _spin_jr(s, dtype)}, wrench=_rotor_inertia_wrench),
    WorldEffect(
        "rotor_drag", "blade flapping and induced drag of each rotor from its own air velocity `v + ω × r_i` at the "
        "rotor hub, above the centre of mass: a lateral force, thrust falling with the rotor's axial inflow, and the "
        "moments of both",
        f"blade flapping and induced drag of each rotor from its own air velocity v_i = v_B + w x r_i, at the rotor "
        f"hub {ROTOR_HUB_HEIGHT * 1e3:g} mm above the centre of mass: F_i = -Omega_i K v_i, K = diag{ROTOR_DRAG} "
        "kg/rad (the z part: thrust falling with the rotor's axial inflow); torque sum r_i x F_i",
        "state, rotor speeds", default=1.0,
        described_by=frozenset({"induced_drag", "linear_drag", "induced_drag_moment", "drag_moment",
                                "induced_rate_damping", "rate_damping", "inflow_thrust_loss"}),
        prepare=_rotor_drag_constants, wrench=_rotor_drag_wrench),
    WorldEffect(
        "body_drag", "quadratic aerodynamic drag of the airframe",
        f"quadratic airframe drag: F_B = -c * |v_B| * v_B per axis, c = {BODY_DRAG} kg/m",
        "state", default=1.0, described_by=frozenset({"quadratic_drag", "linear_drag", "induced_drag"}),
        prepare=lambda s, vehicle, dtype: {"c": s * torch.tensor(BODY_DRAG, dtype=dtype)}, wrench=_body_drag_wrench),
    WorldEffect(
        "telemetry_delay", "the recorded rotor speeds lag the true ones",
        f"the recorded rotor speeds lag the true ones by {TELEMETRY_DELAY * 1e3:g} ms",
        # off in the default world: the rig's motor readings lag its accelerometer by no more than
        # the accelerometer's own filter (reports/rig/world.md, the motor lag)
        "the recorded rotor speeds' history", default=0.0, described_by=frozenset({"input_delay"}),
        truth=("input_delay", lambda s, vehicle: [s * TELEMETRY_DELAY])),
    WorldEffect(
        "thrust_lag", "part of each rotor's thrust and drag torque follows its speed through a slow lag",
        f"a share {SLOW_ACTUATION:g} per unit strength (at most {MAX_SLOW_SHARE:g}) of each rotor's thrust and drag "
        f"torque follows k Omega^2 through a first-order "
        f"lag of {SLOW_ACTUATION_TIME:g} s (the recorded speeds are the rotors'; the wrench lags them)",
        "the rotor speeds' history", default=0.0, described_by=frozenset({"slow_actuation"}),
        truth=("slow_actuation", lambda s, vehicle: [0.0, min(s * SLOW_ACTUATION, MAX_SLOW_SHARE), 0.0])),
    WorldEffect(
        "inertia_offset", "the body's inertia above the nominal",
        f"the body's inertia is ({', '.join(f'{d * 100:+g}' for d in INERTIA_OFFSET)}) % off the nominal diagonal",
        "state, rotor speeds (the body's response)", default=0.0, described_by=frozenset({"inertia", "arm"}),
        truth=("inertia", lambda s, vehicle: [j * s * d for j, d in zip(vehicle.inertia, INERTIA_OFFSET)])),
    WorldEffect(
        "turbulence", "a slow random force and torque: the vehicle's downwash recirculating in the arena",
        f"band-limited random body force and torque (downwash recirculating in the arena): std "
        f"({_mm(TURBULENCE_FORCE)}) mN and ({', '.join(f'{x:g}' for x in TURBULENCE_TORQUE)}) N m, "
        f"low-pass {TURBULENCE_BAND:g} Hz (the torque {', '.join(f'{b:g}' for b in TURBULENCE_TORQUE_BAND)} Hz); a new "
        "realisation "
        "every flight",
        "time: a new random realisation every flight", default=1.0,
        realisation=Realisation((*TURBULENCE_FORCE, *TURBULENCE_TORQUE), (TURBULENCE_BAND,) * 3 + TURBULENCE_TORQUE_BAND,
                                1,
                                lambda d, omega, mixer_t: d)),
    WorldEffect(
        "unsteady_thrust", "each rotor's thrust and drag torque fluctuate around `k Ω²`, and the controller answers "
        "with the rotor speeds",
        "each rotor's thrust and drag torque fluctuate around k Omega^2 (unsteady aerodynamics of the rotor in its "
        f"own disturbed inflow): factors 1 + e_i(t), e_i of std {UNSTEADY_THRUST:.1%}, low-pass "
        f"{UNSTEADY_THRUST_BAND:g} Hz, independent per rotor; a new realisation every flight",
        "time and rotor speeds: a new random realisation every flight", default=0.6,
        realisation=Realisation((UNSTEADY_THRUST,) * 4, UNSTEADY_THRUST_BAND, 2, _unsteady_wrench)),
    WorldEffect(
        "gusts", "a body force and roll/pitch torque in random steps: the arena's air gusting",
        f"body force and roll/pitch torque in steps (the arena's air gusting): std ({_mm(GUST_FORCE)}) mN and "
        f"({', '.join(f'{x:g}' for x in GUST_TORQUE)}) N m, each level held for an exponential time of mean "
        f"{GUST_DWELL:g} s and reached within {GUST_RISE:g} s; a new realisation every flight",
        "time: a new random realisation every flight", default=0.0,
        realisation=Realisation((*GUST_FORCE, *GUST_TORQUE), 1.0 / GUST_DWELL, 3, lambda d, omega, mixer_t: d,
                                _unit_steps)),
)

# name -> record; :func:`register` adds to it
REGISTRY: dict[str, WorldEffect] = {}
# name -> description, what it depends on, and its strength in the default world (those above 0)
EFFECTS: dict[str, str] = {}
DEPENDS_ON: dict[str, str] = {}
DEFAULT_WORLD: dict[str, float] = {}


def register(effect: WorldEffect) -> WorldEffect:
    """Add an effect of nature (after the others in the order of the wrench's sum); its name
    becomes a key of ``sim.effects``."""
    if effect.name in REGISTRY:
        raise ValueError(f"world effect {effect.name!r} is registered already")
    REGISTRY[effect.name] = effect
    EFFECTS[effect.name] = effect.description
    DEPENDS_ON[effect.name] = effect.depends_on
    if effect.default:
        DEFAULT_WORLD[effect.name] = effect.default
    return effect


def unregister(name: str) -> None:
    """Remove an effect added by :func:`register`."""
    del REGISTRY[name], EFFECTS[name], DEPENDS_ON[name]
    DEFAULT_WORLD.pop(name, None)


for _record in RECORDS:
    register(_record)


def state_effects(strengths: Mapping[str, float]) -> dict[str, float]:
    """The strengths of the effects that are functions of the state (no effect of time): the
    world a model of the state can at best learn."""
    return {k: v for k, v in strengths.items() if k not in REGISTRY or not REGISTRY[k].time_varying}


def _channels() -> list[tuple[WorldEffect, slice]]:
    """The time-varying effects and their columns in a flight's realisation."""
    out, start = [], 0
    for e in REGISTRY.values():
        if e.realisation is not None:
            k = len(e.realisation.scale)
            out.append((e, slice(start, start + k)))
            start += k
    return out


@dataclass(frozen=True, eq=False)
class World:
    """Strength of each effect; the ones not named are off."""

    strengths: Mapping[str, float]

    def __post_init__(self) -> None:
        from nanosysid.errors import ConfigError  # the errors a user's mistake raises (no import cycle)

        unknown = sorted(set(self.strengths) - set(EFFECTS))
        if unknown:
            raise ConfigError(f"effects: unknown effect {unknown[0]!r}; the world's effects are {', '.join(EFFECTS)}")
        for name, value in self.strengths.items():
            ok = not isinstance(value, bool) and isinstance(value, (int, float, np.integer, np.floating))
            if not ok or not np.isfinite(value) or value < 0:
                raise ConfigError(f"effects: {name!r} = {value!r}; a world effect's strength is a finite number >= 0 "
                                  "(0 none, 1 the default world's)")

    def s(self, name: str) -> float:
        return float(self.strengths.get(name, 0.0))

    def __str__(self) -> str:
        """The effects that are on and their strengths (``body_drag 1.5, thrust_lag 0.8``), as errors name
        a world."""
        return ", ".join(f"{k} {v:g}" for k, v in sorted(self.strengths.items()) if v) or "no effect"

    @property
    def timed(self) -> bool:
        """Whether an effect of time (a random realisation per flight) is on."""
        return any(self.s(e.name) for e, _ in _channels())

    @property
    def telemetry_delay(self) -> float:
        """Delay (s) of the recorded rotor speeds behind the true ones."""
        return self.s("telemetry_delay") * TELEMETRY_DELAY

    @property
    def slow_share(self) -> float:
        """Share of each rotor's wrench that follows its speed through the slow lag."""
        return min(self.s("thrust_lag") * SLOW_ACTUATION, MAX_SLOW_SHARE)

    def effective_squares(self, s: np.ndarray, dt: float) -> np.ndarray:
        """The squares ``(..., T, 4)`` a rotor's wrench follows, from its speeds' squares ``s``
        sampled every ``dt`` s (the slow lag started at rest at the first sample):
        ``(1 - g) s + g LP(s)``."""
        g = self.slow_share
        if not g:
            return s
        return (1.0 - g) * s + g * _lowpass(s, dt, SLOW_ACTUATION_TIME)

    def inertia(self, vehicle: Vehicle) -> tuple[float, float, float]:
        """The body's true inertia diagonal (kg m^2)."""
        k = self.s("inertia_offset")
        return tuple(j * (1 + k * d) for j, d in zip(vehicle.inertia, INERTIA_OFFSET))

    def disturbance(self, key: Sequence[int], t_end: float) -> np.ndarray | None:
        """The flight's time-varying effects on the realisation grid (:data:`REALISATION_START` +
        n / :data:`REALISATION_RATE`) up to ``t_end`` s, ``(N, channels)``: each time-varying
        effect's channels in registry order (the turbulence's body force (N) and torque (N m),
        then each rotor's relative thrust fluctuation); None when all are off. ``key`` (whole
        numbers) identifies the flight; the same key gives the same realisation, each effect from
        its own stream."""
        if not self.timed:
            return None
        parts = _channels()
        out = np.zeros((int(np.ceil((t_end - REALISATION_START) * REALISATION_RATE)) + 2, parts[-1][1].stop))
        for e, cols in parts:
            if self.s(e.name):
                r = e.realisation
                scale = self.s(e.name) * np.array(r.scale)
                bands = np.broadcast_to(np.asarray(r.band, dtype=float), scale.shape)
                for b in np.unique(bands):
                    # one white noise per stream, filtered once per band: a channel's draw is the
                    # same whatever the other channels' bands
                    here = bands == b
                    noise = r.draw([*key, r.stream], t_end, len(r.scale), float(b))
                    out[:, np.arange(cols.start, cols.stop)[here]] = noise[:, here] * scale[here]
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


def _extra_groups(extra: Sequence[ExtraWrench | None], dtype,
                  complete: bool = False) -> list[tuple[ExtraWrench, Tensor, dict[str, Tensor]]]:
    """The flights' user-supplied wrenches as calls: one per function, and one per family of
    ``functools.partial`` s of one function with numeric keywords (the keywords stacked per
    flight), so that a thousand worlds of one effect at a thousand strengths cost one call.

    Each call comes with its flights: their indices, or with ``complete`` a mask ``(B,)`` (the
    call then runs on every flight, the others with the first one's keywords, and its result
    counts where the mask is set: shapes that do not depend on which flights have it)."""
    groups: dict[tuple, list[int]] = {}
    for i, fn in enumerate(extra):
        if fn is None:
            continue
        key: tuple = (fn, ())
        if isinstance(fn, functools.partial) and not fn.args and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in fn.keywords.values()):
            key = (fn.func, tuple(sorted(fn.keywords)))
        groups.setdefault(key, []).append(i)
    out = []
    for (fn, names), rows in groups.items():
        if complete:
            mask = torch.zeros(len(extra), dtype=torch.bool)
            mask[rows] = True
            of = [i if i in rows else rows[0] for i in range(len(extra))]
            out.append((fn, mask, {k: torch.tensor([extra[i].keywords[k] for i in of], dtype=dtype) for k in names}))
        else:
            out.append((fn, torch.tensor(rows),
                        {k: torch.tensor([extra[i].keywords[k] for i in rows], dtype=dtype) for k in names}))
    return out


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
        complete: Every registered effect computed, at strength 0 where a world has it off (its
            wrench then exactly zero), and the body's inertia always a tensor: the same
            operations whatever the worlds, so that one compiled step serves them all.
    """

    def __init__(self, worlds: Sequence[World], vehicle: Vehicle, *, disturbances: Sequence[np.ndarray | None] = (),
                 extra: Sequence[ExtraWrench | None] | ExtraWrench | None = None, dtype=torch.float64,
                 complete: bool = False) -> None:
        self.B = len(worlds)
        self.vehicle = vehicle

        def stack(values) -> Tensor:  # (B, k)
            return torch.tensor([list(v) for v in values], dtype=dtype)

        def on(e: WorldEffect) -> bool:
            return complete or any(w.s(e.name) for w in worlds)

        active = [e for e in REGISTRY.values() if on(e)]
        s = {e.name: torch.tensor([[w.s(e.name)] for w in worlds], dtype=dtype) for e in active}
        M = dynamics.mixer_matrix(k_f=vehicle.k_f, k_m=vehicle.k_m, arm=vehicle.arm, dtype=dtype)

        def gathered(part: str) -> Tensor | None:  # (B, 4, 6), the sum over the effects that have it
            out = None
            for e in active:
                if getattr(e, part) is not None:
                    m = getattr(e, part)(s[e.name], vehicle, dtype)
                    out = m if out is None else out + m
            return out

        # constants of the active effects, one row per flight, built once
        self.per_omega2 = gathered("per_omega2")
        self.per_omega_rate = gathered("per_omega_rate")
        self.terms = [(e, e.prepare(s[e.name], vehicle, dtype) if e.prepare else {}) for e in active
                      if e.wrench is not None]
        self.channels = [(e, cols) for e, cols in _channels() if on(e)]
        self.mixer_t = M.T
        # (B, 1): each flight's share of the rotors' wrench behind the slow lag
        self.slow_share = None
        if complete or any(w.slow_share for w in worlds):
            self.slow_share = torch.tensor([[w.slow_share] for w in worlds], dtype=dtype)
        self.inertia = None
        if complete or any(w.s("inertia_offset") for w in worlds):
            self.inertia = stack(w.inertia(vehicle) for w in worlds)  # (B, 3)
        self.table = None
        if complete and all(d is None for d in disturbances):
            disturbances = [np.zeros((2, _channels()[-1][1].stop))] if _channels() else []
        if any(d is not None for d in disturbances):
            n, k = max(d.shape for d in disturbances if d is not None)
            if complete:  # a few lengths, not one per flight duration (the last value is held)
                n = max(4096, 1 << (n - 1).bit_length())
            table = np.zeros((self.B, n, k))
            for i, d in enumerate(disturbances):
                if d is not None:
                    table[i, :len(d)] = d
                    table[i, len(d):] = d[-1]
            self.table = torch.from_numpy(table).to(dtype)
        if extra is None or callable(extra):
            self.extra = extra
        else:
            self.extra = list(extra) if any(fn is not None for fn in extra) else None
            self.groups = _extra_groups(self.extra, dtype, complete) if self.extra is not None else []
        self.active = bool(self.terms) or self.per_omega2 is not None or self.per_omega_rate is not None \
            or self.table is not None or self.extra is not None

    @property
    def timed(self) -> bool:
        """Whether the wrench depends on time (turbulence or a user-supplied wrench)."""
        return self.table is not None or self.extra is not None

    def _per_flight(self, v: Tensor, x: Tensor) -> Tensor:
        """``(B, *k)`` constants shaped to broadcast against ``x (B, ..., 13)``."""
        return v.view(v.shape[0], *([1] * (x.dim() - 2)), *v.shape[1:]) if x.dim() > 2 else v

    def _constants(self, x: Tensor) -> tuple[Tensor | None, Tensor | None, list[dict[str, Tensor]]]:
        """The gathered matrices and each term's constants, shaped for ``x`` (cached per shape)."""
        key = (x.dim(), x.dtype)
        cache = self.__dict__.setdefault("_shaped", {})
        if key not in cache:
            def shaped(v):
                return None if v is None else self._per_flight(v.to(x.dtype), x)
            cache[key] = (shaped(self.per_omega2), shaped(self.per_omega_rate),
                          [{k: shaped(v) for k, v in c.items()} for _, c in self.terms])
        return cache[key]

    def lagged(self, omega: Tensor, omega_dot: Tensor, lag: Tensor) -> tuple[Tensor, Tensor]:
        """The speeds ``(B, ..., 4)`` (rad/s) whose squares the rotors' wrench follows, and their
        rates (rad/s^2), from the turning speeds ``omega``, their rates ``omega_dot`` and the
        slow lag's state ``lag`` (LP of ``omega``², rad²/s²): ``sqrt((1 - g) omega² + g lag)``,
        ``g`` the flight's :attr:`World.slow_share`; where ``g`` is 0, ``omega`` and
        ``omega_dot`` themselves (their bytes)."""
        if self.slow_share is None:
            return omega, omega_dot
        g = self._per_flight(self.slow_share.to(omega.dtype), omega)
        w = torch.sqrt((1 - g) * omega * omega + g * lag)
        w_dot = ((1 - g) * omega * omega_dot + g * (omega * omega - lag) / (2 * SLOW_ACTUATION_TIME)) / w
        on = g > 0
        return torch.where(on, w, omega), torch.where(on, w_dot, omega_dot)

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
            if rows.dtype == torch.bool:  # every flight computed, those of the call kept
                f, tq = fn(tt, x, omega, omega_dot, **kw)
                mask = rows.view(*per_flight, 1)
                force, torque = force + torch.where(mask, f, 0.0), torque + torch.where(mask, tq, 0.0)
                continue
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
        per_omega2, per_omega_rate, constants = self._constants(x)
        wrench = None  # (..., 6): force, torque

        def add(w6):
            return w6 if wrench is None else wrench + w6

        if per_omega2 is not None:
            wrench = add((omega * omega).unsqueeze(-1).mul(per_omega2).sum(-2))
        if per_omega_rate is not None:
            wrench = add(omega_dot.unsqueeze(-1).mul(per_omega_rate).sum(-2))
        if self.terms:
            body = Body(x)
            for (e, _), c in zip(self.terms, constants):
                wrench = add(e.wrench(c, body, omega, omega_dot))
        if self.table is not None and self.channels:
            d = self._disturbance(t, x)
            for e, cols in self.channels:
                wrench = add(e.realisation.apply(d[..., cols], omega, self.mixer_t))
        if wrench is None:
            wrench = torch.zeros_like(x[..., :6])
        force, torque = wrench[..., :3], wrench[..., 3:]
        if self.extra is not None:
            f, tq = self._extra(t, x, omega, omega_dot)
            force, torque = force + f, torque + tq
        return force, torque

