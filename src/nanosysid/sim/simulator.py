"""Closed-loop flight simulation of the benchmark vehicle, all flights advancing as one batch.

The physics (rigid body of :mod:`nanosysid.dynamics` plus first-order rotor response and
the hidden effects) is integrated with RK4 at ``physics_rate``; the Mellinger controller runs
at ``control_rate`` on the true state; outputs are sampled at ``output_rate`` with white
measurement noise. Each flight starts with a hover pre-roll (not recorded) that lets the
integrators settle, and is cut to its trajectory's duration.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np
import torch
import torch.nn.functional as F
from scipy.ndimage import uniform_filter1d
from scipy.signal import lfilter
from tqdm.auto import tqdm

from nanosysid import dynamics, so3
from nanosysid.dataio import ACCEL_COLUMNS, INPUT_COLUMNS, OUTPUT_COLUMNS, Flight
from nanosysid.errors import ConfigError
from nanosysid.numerics import LOOP_THREADS, compiled, quiet_tracing, threads
from nanosysid.settings import configured, defaults
from nanosysid.sim.controller import ControllerState, Mellinger, MellingerGains
from nanosysid.sim.trajectories import Reference, make_reference
from nanosysid.sim.world import DEFAULT_WORLD, REALISATION_START, SLOW_ACTUATION_TIME, ExtraWrench, Nature, World
from nanosysid.vehicle import Vehicle

__all__ = ["SimConfig", "NoiseConfig", "FlightSpec", "RawRecord", "simulate", "simulate_raw", "flights_from_record",
           "flight_key", "TRUTH_COLUMNS", "collective_thrust_coefficient", "trajectory_reference", "vibration_scale",
           "accel_bias"]

log = logging.getLogger(__name__)

# s, the span over which the rotors' acceleration sets the airframe's vibration
VIBRATION_WINDOW = 0.2
TRAJECTORY_INDEX = {"square": 0, "random": 1, "chirp": 2, "melon": 3, "yawsweep": 4}
# truth signals stored beside the published columns
WRENCH_COLUMNS = ["fx_body", "fy_body", "fz_body", "tx_body", "ty_body", "tz_body"]
TRUTH_COLUMNS = [f"true_{c}" for c in (*INPUT_COLUMNS, *OUTPUT_COLUMNS, *ACCEL_COLUMNS, *WRENCH_COLUMNS)]


@configured("sim/default.yaml", "flight", "noise")
class NoiseConfig:
    """Standard deviations of white measurement noise at the output rate, and the slowly varying
    error of the onboard velocity estimate (first-order Gauss-Markov: the benchmark's velocity is
    an estimate, not the derivative of the mocap position); defaults and units:
    ``sim.flight.noise`` of ``conf/sim/default.yaml``. ``gyro`` is one std for the three body
    axes or one per axis (roll, pitch, yaw). The gyro's, the accelerometer's and the rotor
    speeds' noise is the airframe's vibration: their std grows with how hard the rotors are
    driven (:func:`vibration_scale`, ``vibration_ref``). ``accel_bias``: std (m/s², per body
    axis) of the accelerometer's bias, new at each power-up (one draw a flight)."""

    pos: float
    vel: float
    vel_drift: float
    vel_drift_tau: float
    att: float
    gyro: float | tuple[float, float, float]
    accel: float
    rotor: float
    vibration_ref: float
    accel_bias: float | tuple[float, float, float]

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any]) -> "NoiseConfig":
        return cls(**{k: tuple(float(x) for x in v) if isinstance(v, (list, tuple)) else float(v)
                      for k, v in dict(cfg).items()})


@configured("sim/default.yaml", "flight", own=("noise", "trajectories", "gains"))
class SimConfig:
    """Rates, motor model, trajectory options and noise of a simulation; defaults and units:
    ``sim.flight`` of ``conf/sim/default.yaml`` (RK4 at ``physics_rate`` with the command held
    between control instants)."""

    physics_rate: float
    control_rate: float
    output_rate: float
    motor_tau: float
    omega_min: float
    omega_max: float
    preroll: float
    postroll: float
    initial_offset: float
    waypoint_seed: int
    feedforward: float
    compile: bool
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    trajectories: Mapping[str, Mapping[str, Any]] = field(
        default_factory=lambda: defaults("sim/default.yaml", "flight", "trajectories"))
    gains: MellingerGains = field(default_factory=MellingerGains)

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any]) -> "SimConfig":
        cfg = dict(cfg)
        noise = NoiseConfig.from_mapping(cfg.pop("noise", None) or {})
        gains = MellingerGains.from_mapping(dict(cfg.pop("gains", None) or {}))
        traj = {k: dict(v) for k, v in dict(cfg.pop("trajectories", None) or {}).items()}
        return cls(noise=noise, gains=gains, trajectories=traj or cls().trajectories, **cfg)


def trajectory_reference(name: str, cfg: SimConfig | None = None) -> Reference:
    """The reference a flight of trajectory ``name`` follows under ``cfg`` (its options, the random
    trajectory's waypoint seed): what the host sends as setpoints."""
    cfg = cfg or SimConfig()
    opts = {k: (tuple(v) if isinstance(v, (list, tuple)) else v) for k, v in cfg.trajectories.get(name, {}).items()}
    if name == "random":
        opts.setdefault("seed", cfg.waypoint_seed)
    return make_reference(name, **opts)


def flight_key(seed: int, trajectory: str, run: int) -> list[int]:
    """The whole numbers every random draw of a flight is seeded from: its seed, trajectory and run."""
    return [int(seed), TRAJECTORY_INDEX.get(trajectory, 9), int(run)]


@dataclass(frozen=True)
class FlightSpec:
    """One flight of a batch, with its own world.

    Attributes:
        trajectory: A trajectory name (``square``, ``random``, ``chirp``, ``melon``) or a
            :class:`~nanosysid.sim.trajectories.Reference`.
        run: Run number; with ``seed`` and the trajectory it seeds the flight's random draws.
        effects: Strength of each world effect; None is the default world, ``{}`` none.
        seed: The flight's seed.
        extra_wrench: A user-supplied ``fn(t, x, omega, omega_dot) -> (force_B, torque_B)``
            (torch tensors, SI units, body frame), added to the world's effects inside the
            integration; None for none.
        name: The flight's name; by default ``<trajectory>_<date>_run<run>``.
    """

    trajectory: str | Reference
    run: int = 1
    effects: Mapping[str, float] | None = None
    seed: int = 0
    extra_wrench: ExtraWrench | None = None
    name: str | None = None

    def __post_init__(self) -> None:
        for key, least in (("run", 1), ("seed", 0)):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < least:
                raise ConfigError(f"FlightSpec: {key} must be a whole number >= {least}, got {v!r}")
        if self.effects is not None:
            self.world  # noqa: B018  (the strengths checked where the flight is named)
        if self.extra_wrench is not None and not callable(self.extra_wrench):
            raise ConfigError(f"FlightSpec: extra_wrench must be a function fn(t, x, omega, omega_dot) -> (force, "
                              f"torque), got {type(self.extra_wrench).__name__}")

    @property
    def world(self) -> World:
        return World(dict(DEFAULT_WORLD) if self.effects is None else dict(self.effects))

    def flight_name(self, date: str) -> str:
        if self.name is not None:
            return self.name
        traj = self.trajectory.name if isinstance(self.trajectory, Reference) else self.trajectory
        return f"{traj}_{date}_run{self.run}"


@dataclass
class RawRecord:
    """The truth of a batch of flights at the physics rate, before any sensor.

    Attributes:
        names, trajectories, runs, seeds, worlds: One entry per flight.
        t: Time ``(N,)`` in s; 0 is the start of the trajectories, negative in the pre-roll.
        x: States ``(B, N, 13)``.
        omega: The speeds ``(B, N, 4)`` (rad/s) whose squares the rotors' wrench follows: the
            turning speeds, unless a slow lag of the wrench (the world's ``thrust_lag``) sets
            the two apart (:meth:`turning`).
        omega_dot: The turning speeds' rates ``(B, N, 4)`` (rad/s^2).
        wrench: Body-frame force (N) and torque (N m) ``(B, N, 6)``, rotors and effects together.
        p_ref: Position setpoints ``(B, N, 3)`` (m), held between control instants.
        yaw_ref: Yaw setpoints ``(B, N)`` (rad), held the same way.
        durations: Trajectory durations (s).
        rngs: Each flight's generator of measurement noise.
        omega_turning: The rotors' turning speeds ``(B, N, 4)`` (rad/s) where they are not
            :attr:`omega`; None where no flight has a slow lag.
    """

    names: list[str]
    trajectories: list[str]
    runs: list[int]
    seeds: list[int]
    worlds: list[World]
    t: np.ndarray
    x: np.ndarray
    omega: np.ndarray
    omega_dot: np.ndarray
    wrench: np.ndarray
    p_ref: np.ndarray
    yaw_ref: np.ndarray
    durations: list[float]
    rngs: list[np.random.Generator]
    omega_turning: np.ndarray | None = None

    def turning(self, i: int) -> np.ndarray:
        """Flight ``i``'s rotor speeds ``(N, 4)`` (rad/s) as the rotors turn: what any record of
        the rotors reads."""
        return self.omega[i] if self.omega_turning is None else self.omega_turning[i]


@threads(LOOP_THREADS)
def simulate_raw(
    flights: Sequence[FlightSpec],
    *,
    vehicle: Vehicle | None = None,
    cfg: SimConfig | None = None,
    date: str = "20250601",
    progress: bool = True,
) -> RawRecord:
    """Simulate a batch of flights, each with its own world, and keep the physics-rate truth.

    A flight's random draws (initial offset, noise, turbulence) depend only on its seed,
    trajectory and run, and its world acts on it alone, so it comes out the same alone or in
    any batch.
    """
    vehicle = vehicle or Vehicle()
    cfg = cfg or SimConfig()
    B = len(flights)
    if not B:
        raise ValueError("simulate: no flight")
    # a compiled step serves one batch size: pad to the next of a few sizes with copies of the
    # last flight (a flight's bytes do not depend on its batch), then drop them
    size = _compiled_batch(B) if cfg.compile else B
    return _simulate_raw([*flights, *[flights[-1]] * (size - B)], vehicle, cfg, date, progress, B)


def _compiled_batch(n: int) -> int:
    """The batch size a compiled simulation of ``n`` flights runs at: 8, 16, 32 or 64, then the
    next multiple of 64 (the step's time hardly depends on it; each size is a compile)."""
    return max(8, 1 << (n - 1).bit_length()) if n <= 64 else -(-n // 64) * 64


def _probe_extra(fn: ExtraWrench, vehicle: Vehicle) -> None:
    """Call a user's extra wrench once on a hovering state, before the flight: it must give a
    force and a torque of the state's leading shape and 3 components, finite. Raises ConfigError
    naming extra_wrench and what it gave."""
    x = torch.zeros(1, 13, dtype=torch.float64)
    x[:, 2], x[:, 9] = 1.0, 1.0
    omega = torch.full((1, 4), float(vehicle.hover_speed), dtype=torch.float64)
    try:
        out = fn(torch.zeros(1, dtype=torch.float64), x, omega, torch.zeros(1, 4, dtype=torch.float64))
        force, torque = out
    except Exception as e:  # a user's function: whatever it raised, named with the call
        raise ConfigError(f"extra_wrench: called as fn(t (1,), x (1, 13), omega (1, 4), omega_dot (1, 4)) on a "
                          f"hovering state, it did not give (force, torque): {type(e).__name__}: {e}") from None
    for what, v in (("force", force), ("torque", torque)):
        shape = tuple(getattr(v, "shape", ()))
        if not torch.is_tensor(v) or shape != (1, 3):
            raise ConfigError(f"extra_wrench: its {what} on states of shape (1, 13) must be a torch tensor of shape "
                              f"(1, 3) (N or N m, body frame), got {type(v).__name__} of shape {shape}")
        if not torch.isfinite(v).all():
            raise ConfigError(f"extra_wrench: its {what} on a hovering state is {v.tolist()}; a wrench must be finite")


def _simulate_raw(flights: Sequence[FlightSpec], vehicle: Vehicle, cfg: SimConfig, date: str, progress: bool,
                  shown: int) -> RawRecord:
    """The batch ``flights`` simulated; the record of its first ``shown``."""
    B = len(flights)
    if cfg.preroll > -REALISATION_START - 5:
        raise ValueError(f"preroll: {cfg.preroll} s is longer than the {-REALISATION_START - 5:g} s the simulator allows")
    refs = [f.trajectory if isinstance(f.trajectory, Reference)
            else trajectory_reference(f.trajectory, cfg) for f in flights]
    keys = [flight_key(f.seed, r.name, f.run) for f, r in zip(flights, refs)]
    rngs = [np.random.default_rng(k) for k in keys]
    worlds = [f.world for f in flights]
    for fn in {id(f.extra_wrench): f.extra_wrench for f in flights if f.extra_wrench is not None}.values():
        _probe_extra(fn, vehicle)

    dt = 1.0 / cfg.physics_rate
    ctrl_every = round(cfg.physics_rate / cfg.control_rate)
    n_pre = round(cfg.preroll * cfg.physics_rate)
    n_steps = n_pre + round((max(r.duration for r in refs) + cfg.postroll) * cfg.physics_rate) + 1
    t_end = (n_steps - 1) * dt - cfg.preroll
    nature = Nature(worlds, vehicle, disturbances=[w.disturbance(k, t_end + 1.0) for w, k in zip(worlds, keys)],
                    extra=[f.extra_wrench for f in flights], complete=cfg.compile)

    # setpoints at every control instant, (B, Nc, 3) each
    t_ctrl = np.arange(0, n_steps, ctrl_every) * dt - cfg.preroll
    pva = [r.pva(t_ctrl) for r in refs]
    p_ref, v_ref, a_ref = (torch.from_numpy(np.stack([x[i] for x in pva])) for i in range(3))
    v_ref, a_ref = v_ref * cfg.feedforward, a_ref * cfg.feedforward
    yaw_ref = torch.from_numpy(np.stack([r.yaw(t_ctrl) for r in refs]))  # (B, Nc)
    yaws = cfg.compile or yaw_ref.any().item()  # a yaw of zero heads as None does: the compiled step takes one

    x = torch.zeros(B, 17, dtype=torch.float64)
    offsets = np.stack([rng.normal(scale=cfg.initial_offset, size=3) for rng in rngs])
    x[:, 0:3] = p_ref[:, 0] + torch.from_numpy(offsets)
    x[:, 9] = 1.0
    x[:, 13:] = vehicle.hover_speed
    lag = torch.full((B, 4), float(vehicle.hover_speed) ** 2, dtype=torch.float64)  # the slow lag at rest in hover
    ctrl = Mellinger(vehicle, cfg.gains, dt=ctrl_every * dt, omega_min=cfg.omega_min, omega_max=cfg.omega_max)
    cstate = ControllerState.zeros(B)
    params = vehicle.dynamics_kwargs()
    if nature.inertia is not None:
        params["inertia"] = nature.inertia
    base = functools.partial(dynamics.quad_dynamics, **params)
    parts = dict(nature=nature, base=base, ctrl=ctrl, motor_tau=cfg.motor_tau, dt=dt,
                 lag_gain=float(-np.expm1(-dt / SLOW_ACTUATION_TIME)))
    advance = _compiled_advance() if cfg.compile else _advance

    # state (17), rotor command (4), the world's wrench (6) and the slow lag (4) at every step
    states, cmds, wrenches, lags = [], [], [], []
    bar = tqdm(total=n_steps, desc=f"simulate {shown} flights", unit="step", unit_scale=True,
               disable=not progress, mininterval=1.0)
    with torch.inference_mode(), quiet_tracing():
        # inputs made here, so that the step sees inference tensors from the first call on
        x, cmd = x.clone(), torch.zeros(B, 4, dtype=torch.float64)
        ctl = torch.cat((cstate.i_pos, cstate.i_att, cstate.prev_ew), -1)
        t_steps = torch.from_numpy(np.arange(n_steps) * dt - cfg.preroll).unsqueeze(-1).expand(n_steps, B)
        for k in range(n_steps):
            control = k % ctrl_every == 0
            j = k // ctrl_every
            states.append(x)
            lags.append(lag)
            x, cmd, ctl, lag, wrench = advance(x, cmd, ctl, lag, p_ref[:, j], v_ref[:, j], a_ref[:, j],
                                               yaw_ref[:, j] if yaws else None, t_steps[k], control=control, **parts)
            cmds.append(cmd)
            wrenches.append(wrench)
            if k % 1000 == 999:
                bar.update(1000)
    bar.update(n_steps - bar.n)
    bar.close()
    B = shown  # the padding's copies are dropped
    rec = torch.cat((torch.stack(states, 1), torch.stack(cmds, 1)), -1)[:B]
    if not torch.isfinite(rec).all():
        i = int((~torch.isfinite(rec).reshape(B, -1).all(1)).nonzero()[0])
        f = flights[i]
        world = "the default world" if f.effects is None else f"effects {dict(f.effects)}"
        extra = " with its extra_wrench" if f.extra_wrench is not None else ""
        raise ConfigError(f"{f.flight_name(date)}: the simulation diverged (a state that is no number) in {world}"
                          f"{extra}: beyond what the controller flies (or check the controller gains and motor model)")

    # body force and torque: the rotors' of the whole record at once, the world's as the loop had it
    t = np.arange(n_steps) * dt - cfg.preroll
    xs, om_turning, cmd_rec = rec[..., :13], rec[..., 13:17], rec[..., 17:]
    om_dot = (cmd_rec - om_turning) / cfg.motor_tau
    om = om_turning
    if nature.slow_share is not None:
        g = nature.slow_share[:B].view(B, 1, 1)
        om = torch.where(g > 0, torch.sqrt((1 - g) * om * om + g * torch.stack(lags, 1)[:B]), om)
    thrust, tau = dynamics.rotor_wrench(om, k_f=vehicle.k_f, k_m=vehicle.k_m, arm=vehicle.arm)
    world = torch.stack(wrenches, 1)[:B]
    f_b, tau = F.pad(thrust.unsqueeze(-1), (2, 0)) + world[..., :3], tau + world[..., 3:]
    p_hold = p_ref[:B].repeat_interleave(ctrl_every, dim=1)[:, :n_steps]
    return RawRecord(
        names=[f.flight_name(date) for f in flights[:B]],
        trajectories=[r.name for r in refs[:B]],
        runs=[f.run for f in flights[:B]],
        seeds=[f.seed for f in flights[:B]],
        worlds=worlds[:B],
        t=t,
        x=xs.numpy(),
        omega=om.numpy(),
        omega_dot=om_dot.numpy(),
        wrench=torch.cat((f_b, tau), -1).numpy(),
        p_ref=p_hold.numpy(),
        yaw_ref=yaw_ref[:B].repeat_interleave(ctrl_every, dim=1)[:, :n_steps].numpy(),
        durations=[r.duration for r in refs[:B]],
        rngs=rngs[:B],
        omega_turning=None if om is om_turning else om_turning.numpy(),
    )


def _advance(x: torch.Tensor, cmd: torch.Tensor, ctl: torch.Tensor, lag: torch.Tensor, p_ref: torch.Tensor,
             v_ref: torch.Tensor, a_ref: torch.Tensor, yaw_ref: torch.Tensor | None, t: torch.Tensor, *,
             control: bool, nature: Nature, base, ctrl: Mellinger, motor_tau: float, dt: float, lag_gain: float):
    """One physics step of the batch ``(B, 17)`` (rigid body and rotor speeds), the controller run
    first at a control instant; ``t (B,)`` is the step's start (s); ``lag (B, 4)`` the slow lag's
    state (rad²/s², the low-passed squares of the turning speeds, held over the step: its time
    constant is a hundred steps). Returns the next state, the rotor command held over the step,
    the controller's state ``(B, 9)`` (``i_pos``, ``i_att``, ``prev_ew``: one tensor, whose layout
    stays the same from step to step), the slow lag's next state (the exact first-order update,
    gain ``lag_gain``, toward the new squares) and the world's body force and torque ``(B, 6)``
    at the step's start."""
    if control:
        cmd, cs = ctrl(x[:, :13], p_ref, v_ref, a_ref, ControllerState(*ctl.split(3, dim=-1)), yaw_ref)
        ctl = torch.cat((cs.i_pos, cs.i_att, cs.prev_ew), -1)

    stages = []  # the world's wrench at each RK4 stage; the first is the step's start

    def deriv(z: torch.Tensor, u: torch.Tensor, tk: torch.Tensor) -> torch.Tensor:
        om = z[:, 13:]
        om_dot = (u - om) / motor_tau
        w, w_dot = nature.lagged(om, om_dot, lag)  # the speeds the wrench follows
        if nature.active:
            force, torque = nature.wrench(tk, z[:, :13], w, w_dot)
        else:
            force, torque = torch.zeros_like(z[:, :3]), torch.zeros_like(z[:, :3])
        stages.append(torch.cat((force, torque), -1))
        return torch.cat((base(z[:, :13], w, force_body=force, torque_body=torque), om_dot), dim=-1)

    x = dynamics.integrate(deriv, x, cmd, dt=dt, substeps=1, t=t)
    if nature.slow_share is not None:
        om = x[:, 13:]
        lag = lag + lag_gain * (om * om - lag)
    return x, cmd, ctl, lag, stages[0]


@functools.cache
def _compiled_advance():
    # the step's few hundred tensor operations fused into a handful of C++ loops, the same bytes
    # on every x86 machine whatever the batch (numerics.compiled)
    return compiled(_advance, setting="sim.flight.compile")


def simulate(
    flights: Sequence[FlightSpec],
    *,
    vehicle: Vehicle | None = None,
    cfg: SimConfig | None = None,
    noise: bool = True,
    date: str = "20250601",
    progress: bool = True,
) -> list[Flight]:
    """Simulate a batch of flights and sample them at the output rate.

    Returns:
        One :class:`Flight` per entry: the published columns (measured, with noise) and the
        truth in ``true_*`` extras (outputs, rotor speeds, specific force, body force and torque).
    """
    vehicle = vehicle or Vehicle()
    cfg = cfg or SimConfig()
    raw = simulate_raw(flights, vehicle=vehicle, cfg=cfg, date=date, progress=progress)
    return flights_from_record(raw, vehicle=vehicle, cfg=cfg, noise=noise)


def flights_from_record(raw: RawRecord, *, vehicle: Vehicle, cfg: SimConfig, noise: bool = True) -> list[Flight]:
    """Sample a raw record at the output rate, with the telemetry delay and measurement noise."""
    every = round(cfg.physics_rate / cfg.output_rate)
    start = int(np.argmin(np.abs(raw.t)))
    out = []
    for i, name in enumerate(raw.names):
        n = round(raw.durations[i] * cfg.output_rate) + 1
        idx = start + every * np.arange(n)
        y_true = raw.x[i, idx]
        omega_true = raw.omega[i, idx]
        turning = raw.turning(i)
        # recorded rotor speeds lag the true ones: sample the true history d seconds earlier
        u_rec = interp_columns(raw.t, turning, raw.t[idx] - raw.worlds[i].telemetry_delay)
        acc_true = raw.wrench[i, idx, :3] / vehicle.mass  # specific force in the body frame
        y, u, acc = y_true.copy(), u_rec, acc_true.copy()
        if noise:
            y, u, acc = _add_noise(y, u, acc, turning[idx], cfg.noise, raw.rngs[i], 1.0 / cfg.output_rate)
        extra = {c: acc[:, j] for j, c in enumerate(ACCEL_COLUMNS)}
        truth = np.concatenate((omega_true, y_true, acc_true, raw.wrench[i, idx]), axis=1)
        extra.update({c: truth[:, j].copy() for j, c in enumerate(TRUTH_COLUMNS)})
        if raw.yaw_ref[i].any():
            extra["yaw_ref"] = raw.yaw_ref[i, idx].copy()
        out.append(Flight(name=name, t=np.round(raw.t[idx], 10), u=u, y=y, extra=extra))
    return out


def interp_columns(t: np.ndarray, values: np.ndarray, t_query: np.ndarray) -> np.ndarray:
    """Linear interpolation of each column of ``values (T, C)`` at ``t_query``."""
    return np.stack([np.interp(t_query, t, values[:, c]) for c in range(values.shape[1])], axis=1)


def perturb_attitude(q: np.ndarray, std: float, rng: np.random.Generator) -> np.ndarray:
    """Quaternions ``(T, 4)`` turned by white rotation-vector noise of ``std`` rad."""
    dq = so3.quat_exp(torch.from_numpy(rng.normal(scale=std, size=(len(q), 3))))
    return so3.quat_mul(torch.from_numpy(np.ascontiguousarray(q)), dq).numpy()


def velocity_drift(n: int, noise: NoiseConfig, dt: float, rng: np.random.Generator) -> np.ndarray:
    """``(n, 3)`` samples of the velocity estimate's slow error: first-order Gauss-Markov with
    std ``noise.vel_drift`` and correlation time ``noise.vel_drift_tau``, started in its
    stationary distribution."""
    a = np.exp(-dt / noise.vel_drift_tau)
    drive = rng.normal(scale=noise.vel_drift * np.sqrt(1 - a * a), size=(n, 3))
    drive[0] = rng.normal(scale=noise.vel_drift, size=3)
    return lfilter([1.0], [1.0, -a], drive, axis=0)


def vibration_scale(omega: np.ndarray, dt: float, ref: float) -> np.ndarray:
    """``(T,)`` factor on the std of the vibration-borne noise (gyro, accelerometer, rotor speeds)
    at samples ``dt`` s apart of the true rotor speeds ``omega (T, 4)`` rad/s: ``sqrt(1 + (a /
    ref)²)``, ``a`` the rotors' mean ``|dOmega/dt|`` (rad/s²) averaged over
    :data:`VIBRATION_WINDOW`. The rig's noise on all three sensors rises from flight to flight
    with how much its rotor speeds move (reports/rig/world.md), not with their level, which
    every trajectory holds near hover; ``ref`` 0: one level throughout."""
    if ref <= 0 or len(omega) < 2:
        return np.ones(len(omega))
    a = np.abs(np.gradient(omega, dt, axis=0)).mean(axis=1)
    a = uniform_filter1d(a, max(1, round(VIBRATION_WINDOW / dt)), mode="nearest")
    return np.sqrt(1.0 + (a / ref) ** 2)


def accel_bias(n: NoiseConfig, rng: np.random.Generator) -> np.ndarray:
    """``(3,)`` the accelerometer's bias of one power-up (m/s², body frame); none drawn where it
    is 0 (a world without it keeps its other draws)."""
    if not np.any(n.accel_bias):
        return np.zeros(3)
    return rng.normal(scale=n.accel_bias, size=3)


def _add_noise(y, u, acc, omega_true, n: NoiseConfig, rng: np.random.Generator, dt: float):
    T = len(y)
    y = y.copy()
    g = vibration_scale(omega_true, dt, n.vibration_ref)[:, None]
    y[:, 0:3] += rng.normal(scale=n.pos, size=(T, 3))
    y[:, 3:6] += rng.normal(scale=n.vel, size=(T, 3))
    if n.vel_drift > 0:
        y[:, 3:6] += velocity_drift(T, n, dt, rng)
    y[:, 6:10] = perturb_attitude(y[:, 6:10], n.att, rng)
    y[:, 10:13] += g * rng.normal(scale=n.gyro, size=(T, 3))
    # a rotor's speed sensor reads a magnitude: a rotor near rest reads 0, never below
    u = np.maximum(u + g * rng.normal(scale=n.rotor, size=u.shape), 0.0)
    acc = acc + g * rng.normal(scale=n.accel, size=acc.shape) + accel_bias(n, rng)
    return y, u, acc


def collective_thrust_coefficient(flights: Sequence[Flight]) -> float:
    """The one k_F of nature's noise-free body thrust on its noise-free sum of squared rotor
    speeds over ``flights`` (simulated, with their ``true_*`` columns). With rotors a few per
    cent apart this is what a one-k_F thrust model can at best identify, not the rotors' mean."""
    num = den = 0.0
    for f in flights:
        p = sum(f.extra[f"true_m{i}_rads"] ** 2 for i in range(1, 5))
        num += float(p @ f.extra["true_fz_body"])
        den += float(p @ p)
    return num / den

