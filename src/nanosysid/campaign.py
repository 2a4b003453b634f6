"""The campaign: discovery on many simulated worlds whose truth is hidden from it.

Each world hides 0 to 3 of the simulator's effects (strengths log-uniform in 0.3 to 3) and,
in some worlds, a user-supplied effect that no library entry describes. Discovery
(:func:`nanosysid.discover.run`) sees only the flights; this module, the judge, knows the
world and scores the verdicts against :data:`DESCRIBED_BY` (the README's table, fixed before
any run): which library entries describe which world effect.

Example::

    from nanosysid import campaign
    draws = campaign.draw(60, seed=0)
    rows = campaign.check(draws, launcher=Launcher(workers=2))   # one row per world
                                                   # (nanosysid.launcher.Launcher)
    summary = campaign.summarize(rows)
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import pandas as pd
import torch

from nanosysid import discover, identify, protocol, sim, so3
from nanosysid.preprocess.lag import LagEvidence, motor_lag_estimate, motor_lag_evidence
from nanosysid.preprocess.sync import SyncConfig
from nanosysid.effects import LIBRARY
from nanosysid.errors import ConfigError, PredictionError, UserError
from nanosysid.launcher import Launcher, even_parts, map_tasks
from nanosysid.sim import EFFECTS, SimConfig
from nanosysid.sim import world as nature
from nanosysid.sim.simulator import collective_thrust_coefficient
from nanosysid.sim.trajectories import make_reference, square
from nanosysid.vehicle import Vehicle

__all__ = ["DESCRIBED_BY", "OUT_OF_LIBRARY", "HiddenWorld", "Setup", "draw", "simulate", "judge", "check", "summarize",
           "identification", "summarize_identification", "library_truth", "coefficient_coverage",
           "short_flights_config", "lag_evidence", "STRENGTH_BINS", "FAMILIES", "families", "summarize_families"]



class _DescribedBy(Mapping[str, frozenset]):
    """World effect -> the library entries that describe it (any of its forms), from each
    effect's record: a "named" verdict is correct when the world has an effect it describes."""

    def __getitem__(self, name: str) -> frozenset[str]:
        return nature.REGISTRY[name].described_by

    def __iter__(self):
        return iter(nature.REGISTRY)

    def __len__(self) -> int:
        return len(nature.REGISTRY)


DESCRIBED_BY: Mapping[str, frozenset[str]] = _DescribedBy()
STRENGTH_BINS = ((0.3, 0.7), (0.7, 1.5), (1.5, 3.0))


def _v_body(x):
    return so3.quat_rotate(so3.quat_conj(x[..., 6:10]), x[..., 3:6])


# User-supplied effects that no library entry describes, each ``fn(t, x, om, om_dot, *, s, k_f)``
# of a strength ``s`` on a vehicle of thrust coefficient ``k_f`` (N s^2/rad^2) (numbers, or
# tensors broadcasting against the states' leading shape: the simulator stacks the keywords of
# many worlds into one call).
def thrust_sag(t, x, om, om_dot, *, s, k_f):
    """The battery sags: thrust falls by 4 % x s over 20 s of flight."""
    f = torch.zeros_like(x[..., :3])
    f[..., 2] = -0.04 * s * k_f * (om ** 2).sum(-1) * torch.clamp(t, min=0.0) / 20.0
    return f, torch.zeros_like(f)


def height_roll(t, x, om, om_dot, *, s, k_f):
    """A flow off the arena's wall: a roll torque growing with height."""
    tau = torch.zeros_like(x[..., :3])
    tau[..., 0] = 2e-5 * s * (x[..., 2] - 1.5)
    return torch.zeros_like(tau), tau


def yaw_coupling(t, x, om, om_dot, *, s, k_f):
    """An airframe asymmetry: a yaw torque from the horizontal velocity's two components."""
    v = _v_body(x)
    tau = torch.zeros_like(v)
    tau[..., 2] = 4e-6 * s * v[..., 0] * v[..., 1]
    return torch.zeros_like(v), tau


OUT_OF_LIBRARY: dict[str, Callable] = {"thrust_sag": thrust_sag, "height_roll": height_roll,
                                       "yaw_coupling": yaw_coupling}


@dataclass(frozen=True)
class HiddenWorld:
    """One hidden world: the simulator's effects (strengths of :class:`nanosysid.sim.World`), an
    optional user effect, the seed."""

    index: int
    effects: dict[str, float]
    user: str | None = None
    user_strength: float = 0.0
    seed: int = 0
    family: str = "mixed"
    runs: int = 1  # runs of each training trajectory (two: runs of one reference to compare)

    def extra_wrench(self, vehicle: Vehicle):
        """The user effect as the simulator's ``extra_wrench`` on ``vehicle`` (None: none)."""
        if self.user is None:
            return None
        return functools.partial(OUT_OF_LIBRARY[self.user], s=self.user_strength, k_f=vehicle.k_f)

    @property
    def clean(self) -> bool:
        return not self.effects and self.user is None


def draw(n: int, seed: int = 0, *, user_share: float = 0.2, max_effects: int = 3) -> list[HiddenWorld]:
    """``n`` worlds drawn from ``seed``: 0 to ``max_effects`` simulator effects each, strengths
    log-uniform in 0.3..3; a share ``user_share`` also get a user effect outside the library.

    Raises:
        ConfigError: ``max_effects`` beyond the simulator's effects, or ``user_share`` outside 0..1.
    """
    rng = np.random.default_rng(seed)
    names = sorted(EFFECTS)
    if isinstance(max_effects, bool) or not isinstance(max_effects, (int, np.integer)) or not 0 <= max_effects <= len(names):
        raise ConfigError(f"campaign: max_effects (campaign.max_effects) = {max_effects!r}; a world draws 0 to at most "
                          f"the simulator's {len(names)} effects")
    if not 0 <= user_share <= 1:
        raise ConfigError(f"campaign: user_share (campaign.user_share) = {user_share!r}; it is the share of worlds "
                          "given an effect outside the library, from 0 to 1")
    out = []
    for i in range(n):
        k = int(rng.integers(0, max_effects + 1))
        chosen = sorted(rng.choice(names, size=k, replace=False).tolist()) if k else []
        effects = {e: float(f"{math.exp(rng.uniform(math.log(0.3), math.log(3.0))):.3g}") for e in chosen}
        user, us = None, 0.0
        if rng.random() < user_share:
            user = str(rng.choice(sorted(OUT_OF_LIBRARY)))
            us = float(f"{math.exp(rng.uniform(math.log(0.3), math.log(3.0))):.3g}")
        out.append(HiddenWorld(i, effects, user, us, int(rng.integers(1, 2**31 - 1))))
    return out


# The families of worlds that test what a disagreement no function of the state explains is a
# function of: a slow lag of the rotors' wrench alone, turbulence alone, gusts alone (a
# disturbance of another shape and spectrum than the turbulence's), the recorded rotor speeds a
# few milliseconds late alone (what the sync stage leaves of the telemetry's delay) (each flown
# twice per training trajectory, so that runs of one reference can be compared), and worlds of
# state effects alone, which must never get that verdict. Only the first may name a slow lag.
STATE_ONLY = ("com_offset", "motor_asymmetry", "rotor_inertia", "rotor_drag", "body_drag", "inertia_offset")
FAMILIES = {"thrust_lag": ("thrust_lag",), "turbulence": ("turbulence",), "gusts": ("gusts",),
            "residual_delay": ("telemetry_delay",), "state": STATE_ONLY}
# the strengths a single-effect family is drawn in (log-uniform), where not 0.5..3: the residual
# delay is 3-9 ms (the telemetry's 30 ms at 0.1-0.3), what the sync stage's estimate leaves
FAMILY_STRENGTHS = {"residual_delay": (0.1, 0.3)}


def families(counts: Mapping[str, int], seed: int = 0, *, start: int = 0) -> list[HiddenWorld]:
    """Worlds of each family of :data:`FAMILIES` (``counts``: family -> number), indices from
    ``start``: the single-effect families at strengths log-uniform in 0.5..3 (or their
    :data:`FAMILY_STRENGTHS`), the state family
    with 2 to 4 of its effects at 0.3..3; every training trajectory flown twice."""
    rng = np.random.default_rng([seed, 7])
    out, i = [], start
    for fam, n in counts.items():
        names = FAMILIES[fam]
        for _ in range(int(n)):
            if len(names) == 1:
                lo, hi = FAMILY_STRENGTHS.get(fam, (0.5, 3.0))
                effects = {names[0]: float(f"{math.exp(rng.uniform(math.log(lo), math.log(hi))):.3g}")}
            else:
                k = int(rng.integers(2, 5))
                effects = {e: float(f"{math.exp(rng.uniform(math.log(0.3), math.log(3.0))):.3g}")
                           for e in sorted(rng.choice(names, size=k, replace=False).tolist())}
            out.append(HiddenWorld(i, effects, None, 0.0, int(rng.integers(1, 2**31 - 1)), family=fam, runs=2))
            i += 1
    return out


def _square_within(options: Mapping[str, Any], duration: float) -> dict[str, Any]:
    """The square's ``options`` changed so that it lasts at most ``duration`` s: its holds
    shortened first, then its moves, with its side and step shrunk as the moves' time squared
    so that its accelerations stay those of ``options``."""
    sq = {**{k: p.default for k, p in inspect.signature(square).parameters.items()}, **options}
    full = make_reference("square", **sq).duration
    moving = make_reference("square", **{**sq, "hold": 0.0}).duration
    if duration >= full:
        return dict(options)
    if duration >= moving:
        return {**sq, "hold": sq["hold"] * (duration - moving) / (full - moving)}
    s = duration / moving
    return {**sq, "hold": 0.0, "move": sq["move"] * s, "side": sq["side"] * s**2, "z_step": sq["z_step"] * s**2}


def short_flights_config(duration: float = 20.0, base: SimConfig | None = None, *,
                         calibration: float | None = None) -> SimConfig:
    """``base`` (the default simulator's config) with every benchmark trajectory ``duration``
    seconds long (the square at most: longer than its 19 s it is flown as it is), and the yaw
    calibration flight ``calibration`` seconds long (None: as ``base`` flies it, so that the
    campaign judges the identification the product runs: a sweep from 0.05 Hz cut to 20 s holds
    one slow cycle, and k_M's estimate from it is two to three times more scattered)."""
    base = base or SimConfig()
    default = base.trajectories
    sweep = dict(default["yawsweep"]) if calibration is None else {
        "duration": calibration, "fade": min(3.0, 0.1 * calibration)}
    return dataclasses.replace(base, trajectories={
        "square": _square_within(default.get("square", {}), duration),
        "random": _random_within(default["random"], duration),
        "melon": {**default["melon"], "duration": duration, "circle_time": 0.75 * duration,
                  "return_time": 0.15 * duration},
        "chirp": {"duration": duration},
        "yawsweep": sweep,
    })


def _random_within(random: Mapping[str, Any], duration: float) -> dict[str, Any]:
    """The Random cut to ``duration`` s at its own pace: given waypoints (a logged reference's),
    as many of its first ones as the flight has time for; drawn ones, about one every 1.1 s."""
    points = random.get("points")
    if points is None:
        return {**random, "duration": duration, "n_points": max(4, int(round(0.9 * duration)))}
    every = float(random.get("duration", 60.0)) / (len(points) - 1)
    return {**random, "duration": duration, "points": list(points)[:max(4, int(round(duration / every)) + 1)]}


@dataclass(frozen=True)
class Setup:
    """What every world of a campaign shares: the nominal vehicle (the simulated body and
    discovery's nominal model), the split of the trajectories (the configuration's ``split``),
    the yaw calibration flight of the identify step (no part of discovery's data), the
    simulator's settings and the sync stage's (the motor lag's estimate), the velocity
    discovery's regressors read (:func:`nanosysid.discover.run`'s ``velocity``) and whether it
    also searches without each training flight (``flights_out``, as the discover stage does: the
    verdict ``unstable`` and the intervals from flights are part of what is judged)."""

    vehicle: Vehicle = field(default_factory=Vehicle)
    train: tuple[str, ...] = ("square", "random", "chirp")
    test: str = "melon"
    calibration: str | None = "yawsweep"
    sim: SimConfig = field(default_factory=short_flights_config)
    sync: SyncConfig = field(default_factory=SyncConfig)
    inertia_z_range: tuple[float, float] | None = None
    velocity: str = "position"
    flights_out: bool = True

    @property
    def trajectories(self) -> tuple[str, ...]:
        return (*self.train, self.test, *([self.calibration] if self.calibration else []))


def simulate(worlds: Sequence[HiddenWorld], setup: Setup | None = None, *,
             progress: bool = False) -> dict[int, tuple[list, dict]]:
    """Every world's flights (training ones, the test one, the calibration one), and its test
    flight flown again without each of its simulator effects (same seed: the same noise and
    realisations), all worlds in one batch. A flight is named ``<trajectory>_w<world>_run1`` (the
    oracle finds its realisation by it). Returns world index -> (flights, effect -> test flight
    without it)."""
    setup = setup or Setup()
    specs, keys = [], []
    for w in worlds:
        extra = w.extra_wrench(setup.vehicle)
        for tr in setup.trajectories:
            for run in range(1, (w.runs if tr in setup.train else 1) + 1):
                specs.append(sim.FlightSpec(trajectory=tr, run=run, effects=w.effects, seed=w.seed,
                                            extra_wrench=extra, name=f"{tr}_w{w.index}_run{run}"))
                keys.append((w.index, None))
        for e in w.effects:
            rest = {k: v for k, v in w.effects.items() if k != e}
            specs.append(sim.FlightSpec(trajectory=setup.test, run=1, effects=rest, seed=w.seed,
                                        extra_wrench=extra, name=f"{setup.test}_w{w.index}_run1"))
            keys.append((w.index, e))
    flights = sim.simulate_flights(specs, cfg=setup.sim, vehicle=setup.vehicle, progress=progress)
    out: dict[int, tuple[list, dict]] = {w.index: ([], {}) for w in worlds}
    for (i, e), f in zip(keys, flights):
        if e is None:
            out[i][0].append(f)
        else:
            out[i][1][e] = f
    return out


def _relative_gap(before, after, oracle) -> float | None:
    """Share of the nominal-to-oracle SimErr gap closed, each quantity relative to the nominal's
    (``before``: the best nominal row's)."""
    gap = sum((before[q] - oracle[q]) / before[q] for q in before)
    if gap <= 0:
        return None
    return float(sum((before[q] - after[q]) / before[q] for q in before) / gap)


def judge(world: HiddenWorld, flights: Sequence, without: dict | None = None, *, setup: Setup | None = None,
          horizon: int = 50) -> dict[str, Any]:
    """Discovery on one world's flights, and its verdicts scored against the world; ``without``
    (effect -> the test flight flown without it) gives each effect's impact on the nominal SimErr.
    Discovery's nominal model is the setup's vehicle with k_F and k_M as the identify stage gives
    them (:func:`identification`): what discovery starts from in the pipeline."""
    setup = setup or Setup()
    train = [f for f in flights if f.trajectory in setup.train]
    test = [f for f in flights if f.trajectory == setup.test]
    try:
        ident, nominal = _identified(world, flights, setup)
    except UserError as e:  # what the identify stage would refuse, named with the world that made it
        raise type(e)(f"world {world.index} ({nature.World(world.effects)}): its flights cannot be identified: "
                      f"{e}") from None
    extra = world.extra_wrench(setup.vehicle)
    oracle = sim.oracle(world.effects, vehicle=setup.vehicle, seed=world.seed, extra_wrench=extra,
                        compile=setup.sim.compile)
    try:
        r = discover.run(train, test, vehicle=nominal, oracle=oracle, sindy=True, analysis=False, horizon=horizon,
                         inertia_z_range=setup.inertia_z_range, diverged_ok=True, velocity=setup.velocity,
                         flights_out=setup.flights_out)
    except PredictionError as e:  # a rollout other than the augmented model's diverges: the world fails
        return {"world": world.index, "seed": world.seed, "effects": dict(world.effects), "user": world.user,
                "user_strength": world.user_strength, "error": str(e), "identify": ident, "family": world.family}
    # each effect's impact: how far the nominal model's SimErr on the test flight moves when the
    # world loses that effect (largest relative change over the four quantities)
    impact = {}
    for e, flight in (without or {}).items():
        other = protocol.evaluate(r.nominal, [flight], horizon=horizon).simerr
        impact[e] = float(max(abs(r.before.simerr[q] - other[q]) / r.before.simerr[q] for q in other))
    # the gap a model of the state can close: to the oracle that knows every effect but the
    # time-varying ones (turbulence, the thrust fluctuation)
    state = nature.state_effects(world.effects)
    reachable = protocol.evaluate(sim.oracle(state, vehicle=setup.vehicle, seed=world.seed, extra_wrench=extra,
                                             compile=setup.sim.compile),
                                   test, horizon=horizon).simerr if state != world.effects else r.oracle.simerr
    best = r.best_nominal  # the gap a model closes is measured from the better of physics_full and physics
    named = [f.name for f in r.findings if f.verdict == "named"]
    ambiguous = [list(f.alternatives) for f in r.findings if f.verdict == "ambiguous"]
    described = set().union(*(DESCRIBED_BY[e] for e in world.effects)) if world.effects else set()
    offered = set(named) | {a for alts in ambiguous for a in alts}
    return {
        "world": world.index, "seed": world.seed, "effects": dict(world.effects), "user": world.user,
        "user_strength": world.user_strength,
        "named": named, "ambiguous": ambiguous, "unnamed": [list(f.channels) for f in r.findings if f.verdict == "unnamed"],
        "false_named": [n for n in named if n not in described],
        "recalled": {e: bool(DESCRIBED_BY[e] & offered) for e in world.effects},
        "impact": impact,
        "simerr": {"nominal": r.before.simerr, "physics": r.held_rate.simerr, "discovered": r.after.simerr,
                   "oracle": r.oracle.simerr, "sindy": r.sindy["simerr"]},
        "gap_closed": None if r.diverged else _relative_gap(best, r.after.simerr, reachable),
        "diverged": r.diverged,
        "sindy_gap_closed": _relative_gap(best, r.sindy["simerr"], reachable),
        "sindy_terms": len(r.sindy["terms"]),
        "gap_share": float(sum((best[q] - reachable[q]) / best[q] for q in best) / 4),
        "identify": ident,
        "coverage": coefficient_coverage(world, r.findings, setup.vehicle),
        "family": world.family,
        "sources": [(f.evidence.get("source") or {}).get("source", "undecided")
                    for f in r.findings if f.verdict == discover.STATELESS],
        "history_dropped": [d["entry"] for d in r.dropped],
        "repeats": [c for f in r.findings if f.verdict == "unnamed" and f.evidence.get("repeats") for c in f.channels],
        "inertia_z": _inertia_z(world, r, setup),
    }


def _inertia_z(world: HiddenWorld, r, setup: Setup) -> dict[str, Any]:
    """The augmented model's yaw inertia against the world's, and whether discovery says it
    identified it (the inertia correction chosen with an interval inside the plausible range)."""
    true = sim.World(dict(world.effects)).inertia(setup.vehicle)[2]
    model = r.vehicle.inertia[2]
    f = next((f for f in r.findings if f.entry == "inertia"), None)
    claimed = f is not None and "inertia_z_range" not in f.evidence
    return {"true": float(true), "model": float(model), "error": float(model / true - 1), "claimed": bool(claimed)}


def summarize_families(rows: Sequence[dict[str, Any]], *, tolerance: float = 0.10) -> dict[str, Any]:
    """Per family of :data:`FAMILIES`: how often the slow lag is named, how often a finding is
    called "not a function of the state" and what of (time, undecided), how often a residual no
    state function captures repeats with the reference (left unnamed), and
    the yaw inertia within ``tolerance`` of the truth or not claimed identified."""
    out = {}
    for fam in FAMILIES:
        rs = [r for r in rows if r.get("family") == fam and "error" not in r]
        if not rs:
            continue
        out[fam] = {
            "worlds": len(rs),
            "failed": sum(1 for r in rows if r.get("family") == fam and "error" in r),
            "slow_actuation_named": sum("slow_actuation" in r["named"] for r in rs),
            "slow_actuation_offered": sum("slow_actuation" in r["named"] or any("slow_actuation" in a for a in r["ambiguous"])
                                          for r in rs),
            "slow_actuation_dropped": sum("slow_actuation" in r["history_dropped"] for r in rs),
            "stateless": sum(bool(r["sources"]) for r in rs),
            "of_time": sum("time" in r["sources"] for r in rs),
            "repeats": sum(bool(r.get("repeats")) for r in rs),
            "diverged": sum(bool(r.get("diverged")) for r in rs),
            "inertia_z_within": sum(abs(r["inertia_z"]["error"]) <= tolerance for r in rs),
            "inertia_z_claimed": sum(r["inertia_z"]["claimed"] for r in rs),
            "inertia_z_claimed_within": sum(r["inertia_z"]["claimed"] and abs(r["inertia_z"]["error"]) <= tolerance
                                            for r in rs),
            "inertia_z_tolerance": tolerance,
        }
    return out


def library_truth(effects: dict[str, float], vehicle: Vehicle) -> dict[str, dict[str, float]]:
    """The world's truth in the parametrisation of the library entries that describe it one to
    one (the judge's translation, written from the world's constants): library entry ->
    coefficient name -> value. The drags' entries have other forms than the world's rotor and
    airframe drag and are left out."""
    out = {}
    for effect, strength in effects.items():
        truth = nature.REGISTRY[effect].truth
        if truth is not None:
            name, fn = truth
            out[name] = dict(zip(LIBRARY[name].params, fn(float(strength), vehicle)))
    return out


def coefficient_coverage(world: HiddenWorld, findings: Sequence, vehicle: Vehicle) -> list[dict[str, Any]]:
    """For every named finding whose entry describes one of the world's effects one to one
    (:func:`library_truth`), each coefficient's truth against its 95 % interval."""
    truth = library_truth(world.effects, vehicle)
    out = []
    for f in findings:
        if f.verdict != "named" or f.name not in truth:
            continue
        for k, v in truth[f.name].items():
            lo, hi = f.evidence["ci"][k]
            out.append({"entry": f.name, "param": k, "truth": v, "value": f.params[k], "low": lo, "high": hi,
                        "covered": bool(lo <= v <= hi)})
    return out


def identification(world: HiddenWorld, flights: Sequence, setup: Setup | None = None) -> dict[str, Any]:
    """The sync and identify steps on one world's flights against the world's truth: the motor
    telemetry's lag (all its flights, one session, with the setpoints as instruments), then, with the rotor speeds
    moved by it, k_F (least squares on the training flights) and k_M (instrumental variables on
    the calibration flight; the paper's least squares on the training flights beside). Errors
    relative to the truth, and whether each 95 % interval covers it (k_M's with the yaw inertia
    anywhere in ``setup.inertia_z_range``, and with the vehicle's taken as exact); k_M counts as
    identifiable where the world's inertia is the nominal one (the gyro's torque is read with it)."""
    return _identified(world, flights, setup)[0]


def lag_evidence(flight, setup: Setup | None = None) -> LagEvidence:
    """What one simulated flight says about its motor telemetry's lag, as the sync step reads it
    from the bags: the accelerometer, the rotor speeds as recorded, the onboard estimate and the
    host's setpoints (the reference of the flight's trajectory under the setup's simulator)."""
    setup = setup or Setup()
    f = flight
    setpoint = pd.DataFrame(sim.trajectory_reference(f.trajectory, setup.sim).pva(f.t)[0], columns=["x", "y", "z"])
    odom = pd.DataFrame(f.y[:, 3:10], columns=["vx", "vy", "vz", "qx", "qy", "qz", "qw"])
    return motor_lag_evidence(f.name, pd.DataFrame({"t_src": f.t, "az": f.extra["az_body"]}),
                              pd.DataFrame({"t_src": f.t, **{f"m{i + 1}": f.u[:, i] for i in range(4)}}), setup.sync,
                              setpoint=setpoint.assign(t_src=f.t), odom=odom.assign(t_src=f.t))


def _identified(world: HiddenWorld, flights: Sequence, setup: Setup | None = None) -> tuple[dict[str, Any], Vehicle]:
    """:func:`identification`'s row, and the setup's vehicle with the k_F and k_M the identify
    stage would write (k_M by instrumental variables where there is a calibration flight, else
    the paper's least squares)."""
    setup = setup or Setup()
    cfg = setup.sync
    lag = motor_lag_estimate([lag_evidence(f, setup) for f in flights], cfg)
    truth_lag = sim.World(dict(world.effects)).telemetry_delay

    def aligned(f):
        return dataclasses.replace(f, u=np.column_stack([np.interp(f.t + lag.value, f.t, f.u[:, i]) for i in range(4)]))

    train = [aligned(f) for f in flights if f.trajectory in setup.train]
    cal = [aligned(f) for f in flights if f.trajectory == setup.calibration]
    vehicle = setup.vehicle
    thrust = identify.fit_thrust(train, vehicle)
    paper = identify.fit_yaw_moment(train, vehicle)
    k_f_target = collective_thrust_coefficient([f for f in flights if f.trajectory in setup.train])
    out: dict[str, Any] = {
        "lag_true": truth_lag, "lag": lag.value, "lag_error": lag.value - truth_lag, "lag_events": lag.events,
        "lag_covered": None if lag.interval[0] is None else bool(lag.interval[0] <= truth_lag <= lag.interval[1]),
        "k_f_error": thrust.coef / vehicle.k_f - 1,
        # one training flight gives no interval (it comes from independent flights): not counted
        "k_f_covered": None if thrust.ci95 is None else bool(thrust.ci95[0] <= k_f_target <= thrust.ci95[1]),
        "k_m_identifiable": "inertia_offset" not in world.effects,
        "k_m_paper_error": paper.coef / vehicle.k_m - 1,
    }
    yaw = paper
    if cal:
        yaw = identify.with_inertia_range(identify.fit_yaw_moment_iv(cal, vehicle, blocks=6), vehicle.inertia[2],
                                          setup.inertia_z_range)
        out["k_m_error"] = yaw.coef / vehicle.k_m - 1
        out["k_m_covered_given_inertia"] = None if yaw.ci95 is None else bool(yaw.ci95[0] <= vehicle.k_m <= yaw.ci95[1])
        ci = yaw.ci95 if yaw.ci95_inertia is None else yaw.ci95_inertia
        out["k_m_covered"] = None if ci is None else bool(ci[0] <= vehicle.k_m <= ci[1])
    return out, dataclasses.replace(vehicle, k_f=thrust.coef, k_m=yaw.coef)


def _check_chunk(worlds: Sequence[HiddenWorld], setup: Setup, horizon: int) -> list[dict[str, Any]]:
    """One task of the launcher: a few worlds simulated in one batch, then judged one by one."""
    flights = simulate(worlds, setup)
    return [judge(w, *flights[w.index], setup=setup, horizon=horizon) for w in worlds]


def check(worlds: Sequence[HiddenWorld], *, launcher=None, setup: Setup | None = None, horizon: int = 50, chunk: int = 4,
          progress: bool = True) -> list[dict[str, Any]]:
    """Simulate and judge every world, at most ``chunk`` worlds to a task of ``launcher``
    (:class:`nanosysid.launcher.Launcher`; None: local processes, one per core), in even tasks
    whose count is a multiple of the launcher's slots (:func:`~nanosysid.launcher.even_parts`).
    The rows come back in the worlds' order, the same whatever the launcher, its number of
    workers and the chunk: a world's flights are the same bytes in any batch."""
    setup = setup or Setup()
    spans = even_parts(len(worlds), chunk, (launcher or Launcher()).slots)
    tasks = [(list(worlds[p.start:p.stop]), setup, horizon) for p in spans]
    size = max((len(p) for p in spans), default=0)
    parts = map_tasks(_check_chunk, tasks, launcher, progress=progress, desc=f"worlds ({size} a task)",
                      name="nanosysid-campaign")
    return [row for part in parts for row in part]


def summarize(rows: Sequence[dict[str, Any]], *, relevant: float = 0.10) -> dict[str, Any]:
    """The worlds check's figures: recall per effect and strength bin (among worlds where the
    effect moves the nominal SimErr by more than ``relevant``), precision of named verdicts,
    clean worlds without a finding, out-of-library worlds without a false name, gap closed, and
    the plain SINDy model beside."""
    failed = [r for r in rows if "error" in r]
    rows = [r for r in rows if "error" not in r]
    recall: dict[str, dict[str, list[int]]] = {}
    for r in rows:
        for e, s in r["effects"].items():
            if not DESCRIBED_BY[e]:
                continue
            b = next((f"{lo:g}-{hi:g}" for lo, hi in STRENGTH_BINS if lo <= s <= hi), "other")
            cell = recall.setdefault(e, {}).setdefault(b, [0, 0, 0, 0])  # hit, n (relevant); hit, n (all)
            cell[2] += r["recalled"][e]
            cell[3] += 1
            if r["impact"].get(e, 0.0) > relevant:
                cell[0] += r["recalled"][e]
                cell[1] += 1
    named = sum(len(r["named"]) for r in rows)
    false = sum(len(r["false_named"]) for r in rows)
    clean = [r for r in rows if not r["effects"] and r["user"] is None]
    ool = [r for r in rows if r["user"] is not None]
    state = [r for r in rows if r["gap_closed"] is not None and r["gap_share"] > 0.05
             and nature.state_effects(r["effects"])]
    both = [r for r in rows if r["gap_closed"] is not None and r["sindy_gap_closed"] is not None and r["gap_share"] > 0.05]
    relevant_hits = {e: {b: (c[0] / c[1] if c[1] else None) for b, c in bins.items()} for e, bins in recall.items()}
    overall = {e: (sum(c[0] for c in bins.values()) / max(1, sum(c[1] for c in bins.values())))
               for e, bins in recall.items()}
    return {
        "worlds": len(rows) + len(failed),
        "relevant": relevant,
        "strength_bins": [list(b) for b in STRENGTH_BINS],
        "failed": len(failed),
        "recall_relevant": relevant_hits,
        "recall_relevant_overall": overall,
        "recall_counts": {e: {b: {"hit_relevant": c[0], "relevant": c[1], "hit": c[2], "worlds": c[3]}
                              for b, c in bins.items()} for e, bins in recall.items()},
        "named": named,
        "precision": None if not named else 1 - false / named,
        "clean_worlds": len(clean),
        "clean_without_finding": None if not clean else sum(not r["named"] and not r["ambiguous"] and not r["unnamed"]
                                                           for r in clean) / len(clean),
        "out_of_library_worlds": len(ool),
        "out_of_library_without_false_name": None if not ool else sum(not r["false_named"] for r in ool) / len(ool),
        "state_worlds": len(state),
        "half_gap_closed": None if not state else sum(r["gap_closed"] >= 0.5 for r in state) / len(state),
        "gap_closed_median": None if not state else float(np.median([r["gap_closed"] for r in state])),
        "sindy_gap_closed_median": None if not both else float(np.median([r["sindy_gap_closed"] for r in both])),
        "beats_sindy": None if not both else sum(r["gap_closed"] > r["sindy_gap_closed"] for r in both) / len(both),
        "sindy_terms_mean": float(np.mean([r["sindy_terms"] for r in rows])) if rows else None,
        "identify": summarize_identification([r["identify"] for r in [*rows, *failed] if "identify" in r]),
        "coefficients_checked": sum(len(r.get("coverage", [])) for r in rows),
        "coefficients_covered": (None if not any(r.get("coverage") for r in rows) else
                                 float(np.mean([c["covered"] for r in rows for c in r.get("coverage", [])]))),
    }


def summarize_identification(ident: Sequence[dict[str, Any]], *, lag_tolerance: float = 0.003,
                             k_m_tolerance: float = 0.10, k_f_tolerance: float = 0.01) -> dict[str, Any]:
    """The identification's figures over the worlds: the motor lag within ``lag_tolerance`` s,
    k_M within ``k_m_tolerance`` (among the worlds that leave it identifiable) and k_F within
    ``k_f_tolerance`` of the truth, how often each interval covers it, and the error quantiles."""
    if not ident:
        return {}

    def share(xs):
        xs = [x for x in xs if x is not None]
        return None if not xs else float(np.mean(xs))

    def quantiles(xs):
        a = np.abs(np.asarray([x for x in xs if x is not None], dtype=float))
        return None if not len(a) else {q: float(np.quantile(a, v)) for q, v in (("median", 0.5), ("p90", 0.9),
                                                                                ("p95", 0.95), ("max", 1.0))}

    km = [r for r in ident if "k_m_error" in r]
    ok = [r for r in km if r["k_m_identifiable"]]
    return {
        "worlds": len(ident),
        "lag_within": share(abs(r["lag_error"]) <= lag_tolerance for r in ident),
        "lag_tolerance": lag_tolerance,
        "lag_covered": share(r["lag_covered"] for r in ident),
        "lag_abs_error": quantiles(r["lag_error"] for r in ident),
        "k_f_within": share(abs(r["k_f_error"]) <= k_f_tolerance for r in ident),
        "k_f_tolerance": k_f_tolerance,
        "k_f_covered": share(r["k_f_covered"] for r in ident),
        "k_f_abs_error": quantiles(r["k_f_error"] for r in ident),
        "k_m_worlds": len(km),
        "k_m_identifiable_worlds": len(ok),
        "k_m_within": share(abs(r["k_m_error"]) <= k_m_tolerance for r in ok),
        "k_m_tolerance": k_m_tolerance,
        "k_m_covered": share(r["k_m_covered"] for r in km),
        "k_m_covered_given_inertia": share(r["k_m_covered_given_inertia"] for r in km),
        "k_m_abs_error": quantiles(r["k_m_error"] for r in ok),
        "k_m_paper_abs_error": quantiles(r["k_m_paper_error"] for r in ident),
    }
