"""Physical consistency of a flight's columns, checked where flights enter (every source).

A flight's columns describe one motion, so each can be checked against another by a physical law,
whatever the source. A column in another unit or convention breaks one of those laws by a factor
far outside the sensors' noise, and the check names the column, the factor found and the likely
cause:

- the accelerometer against gravity: the specific force's median magnitude is about g;
- the attitude against the accelerometer: rotated to the world, the mean specific force points
  up (a quaternion in w, x, y, z order, or of the inverse rotation, turns it away);
- the body rates against the attitude's change: over 0.1 s, the rotation between two attitudes is
  the integral of the body rates;
- the velocity against the specific force: over 0.5 s, the velocity's change is the integral of
  the specific force rotated to the world, less gravity (an offset per axis allowed: the
  accelerometer's bias);
- the position against the velocity: over 0.2 s, the position's change is the velocity's integral;
- the rotor speeds' level against the thrust: ``k_F`` = mass × mean specific force / mean ΣΩ²
  lies within a factor of :data:`K_F_FACTOR` of the vehicle's, the speeds are positive and below
  the motor's no-load speed;
- a stuck logger: every output the same for :data:`STUCK_S` or longer.

Each ratio is a least-squares slope over windows, judged only on an axis that moves enough to
tell (its windowed signal above :data:`MOVES`, far above the sensors' noise) and only where the
two signals agree in shape (correlation above :data:`SHAPE`); a frame or order mistake shows as a
shape that does not agree. On the simulated world's flights and the paper's real flights (their
logs as read, and as filtered) every slope lies within 0.72-1.08 and the rotors' k_F ratio within
0.94-1.02 (``tests/test_consistency.py`` checks every one of them). A unit mistake in the motion's
columns is a factor of 9.8 (g) or more, well outside :data:`SLOPE_BAND`; one in the rotor speeds
is a factor of 2 (pole pairs) or more, a factor of 4 in k_F, outside :data:`K_F_FACTOR`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from nanosysid.errors import DataError

__all__ = ["Expect", "Columns", "CSV_COLUMNS", "check", "check_flight", "STUCK_S", "SLOPE_BAND", "K_F_FACTOR",
           "NO_LOAD_SPEED"]

SLOPE_BAND = (0.5, 2.0)  # a slope between two columns that agree; unit mistakes lie far outside
SHAPE = 0.5  # correlation of two signals of one motion in one frame (the flights: 0.90 or more); a swapped or
# negated axis gives about 0 or less
K_F_FACTOR = 2.5  # the rotor level's k_F within this factor of the vehicle's (the flights: 0.99-1.02)
# rad/s: 10 000 KV at 4.2 V (crazyflie-physics-facts §1); logged speeds above half again as much are
# no rotor speed of this class of vehicle
NO_LOAD_SPEED = 4400.0
STUCK_S = 1.0  # s of every output unchanged: a logger that stopped, not a vehicle at rest (sensor noise)
# windowed signal an axis needs to be judged: position 2 cm per 0.2 s, velocity 0.1 m/s per 0.5 s,
# rotation 0.02 rad per 0.1 s (tens of times the sensors' noise over a window)
MOVES = {"position": 0.02, "velocity": 0.1, "rates": 0.02}
WINDOWS = {"position": 0.2, "velocity": 0.5, "rates": 0.1}  # s
MIN_WINDOWS = 12  # a group is judged on this many windows or more (a few seconds of a log cut short are not)


@dataclass(frozen=True)
class Expect:
    """What the flights' vehicle sets: ``mass`` (kg), ``k_f`` (N s²/rad²), ``gravity`` (m/s²)."""

    mass: float
    k_f: float
    gravity: float = 9.81


@dataclass(frozen=True)
class Columns:
    """How a source names each group of columns, for the messages."""

    position: str
    velocity: str
    attitude: str
    rates: str
    accel: str
    rotors: str


CSV_COLUMNS = Columns("x, y, z", "vx, vy, vz", "qx, qy, qz, qw", "wx, wy, wz", "ax_body, ay_body, az_body",
                      "m1_rads..m4_rads")

# factors a column is commonly off by, and what each means, per group: (factor, cause)
_LIKELY = {
    "accel": [(1 / 9.81, "in g rather than m/s²"), (1000 / 9.81, "in mg rather than m/s²"), (1000, "in mm/s²")],
    "rates": [(180 / np.pi, "in deg/s rather than rad/s"), (1 / (180 / np.pi), "in rad/s where deg/s is read")],
    "velocity": [(10, "ten times too large"), (0.1, "ten times too small"), (1000, "in mm/s rather than m/s"),
                 (100, "in cm/s rather than m/s")],
    "position": [(1000, "in mm rather than m"), (100, "in cm rather than m"), (10, "ten times too large")],
    # the velocity judged by the position it should integrate to, by that slope (position / velocity)
    "velocity_inverse": [(0.1, "ten times too large"), (10, "ten times too small"), (1e-3, "in mm/s rather than m/s"),
                         (1e-2, "in cm/s rather than m/s")],
    "rotors": [(30 / np.pi, "in rpm rather than rad/s"), (60 * 30 / np.pi, "in rpm × 60"), (2, "twice the speed: the "
               "pole pairs halved?"), (0.5, "half the speed: the pole pairs doubled?"), (1 / 60, "a 60th: rpm "
               "read as rps, or eRPM units?"), (60, "60 times: eRPM units?"), (1 / (30 / np.pi), "in rad/s "
               "where rpm is read")],
}


def _likely(group: str, factor: float) -> str:
    """The common mistake a factor matches within 15 %, or a plain statement of the factor."""
    for f, cause in _LIKELY.get(group, []) if np.isfinite(factor) and factor > 0 else []:
        if abs(np.log(factor / f)) < np.log(1.15):
            return f"{factor:.3g} times the expected: {cause}"
    return f"{factor:.3g} times the expected"


def _windows(n: int, w: int) -> np.ndarray:
    return np.arange(0, n - w, w)


def _integral(x: np.ndarray, dt: float, start: np.ndarray, w: int) -> np.ndarray:
    """The trapezoidal integral of ``x`` ``(T, k)`` over each window ``[start, start + w]``."""
    c = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum((x[1:] + x[:-1]) / 2 * dt, axis=0)])
    return c[start + w] - c[start]


def _slopes(a: np.ndarray, b: np.ndarray, *, offset: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per column: the least-squares slope of ``a`` on ``b`` ``(N, k)`` (with an offset where
    ``offset``), their correlation, and the RMS of ``b`` about its mean (or zero)."""
    if offset:
        a, b = a - a.mean(0), b - b.mean(0)
    # values far out of any unit's range (1e300) overflow to inf: the judge refuses them as such
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        bb, ab, aa = (b * b).sum(0), (a * b).sum(0), (a * a).sum(0)
        return ab / bb, ab / np.sqrt(aa * bb), np.sqrt(bb / max(len(b), 1))


def _judge(group: str, cols: str, against: str, a: np.ndarray, b: np.ndarray, where: str, *,
           offset: bool = False, other: tuple[str, str] | None = None) -> list[float]:
    """Refuse ``cols`` (group ``group``) where, on an axis that moves, ``a`` does not follow ``b``
    (``against`` says what ``b`` is); the slopes of the judged axes. ``other`` (group, columns)
    names ``b``'s own columns where no earlier check vouched for them: the message then names both."""
    slope, corr, size = _slopes(a, b, offset=offset)
    judged = [k for k in range(a.shape[1]) if np.isfinite(size[k]) and size[k] > MOVES[group]]
    names = [c.strip() for c in cols.split(",")]
    others = [c.strip() for c in other[1].split(",")] if other else []
    for k in judged:
        if not corr[k] > SHAPE and not abs(slope[k]) > 3 * SLOPE_BAND[1]:
            name = names[k] if len(names) == len(slope) else cols
            also = f" (or {others[k]!r} does not)" if len(others) == len(slope) else ""
            raise DataError(f"{where}: column {name!r} does not follow {against}{also}: correlation {corr[k]:.2f}, "
                            f"below {SHAPE:g}; another frame, an axis swapped or negated?")
    off = [k for k in judged if not SLOPE_BAND[0] <= slope[k] <= SLOPE_BAND[1]]
    if off:
        factor = float(np.median(slope[off]))
        shown = cols if len(off) == len(judged) > 1 else (names[off[0]] if len(names) == len(slope) else cols)
        cause = _likely(group, factor)
        if other:
            flipped = _likely(other[0], factor)
            if "times the expected:" in flipped:
                cause += f"; or {other[1]!r} {flipped.split(': ', 1)[1]}"
        raise DataError(f"{where}: column(s) {shown!r} against {against}: {cause} (slope {factor:.4g}; agreeing "
                        f"columns lie within {SLOPE_BAND[0]:.2f}-{SLOPE_BAND[1]:.2f})")
    return [float(slope[k]) for k in judged]


def _stuck(y: np.ndarray) -> tuple[int, int]:
    """The longest run of rows whose every column equals the previous row's: (first, last)."""
    same = np.all(np.diff(y, axis=0) == 0, axis=1).astype(np.int8)
    if not same.any():
        return 0, 0
    edges = np.diff(np.concatenate([[0], same, [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    k = int(np.argmax(ends - starts))
    return int(starts[k]), int(ends[k])


def check(t: np.ndarray, u: np.ndarray, y: np.ndarray, accel: np.ndarray, expect: Expect, where: str,
          columns: Columns = CSV_COLUMNS) -> dict:
    """Check one flight's columns against each other (module docstring).

    Args:
        t: ``(T,)`` s, sampled about evenly.
        u: ``(T, 4)`` rotor speeds, rad/s.
        y: ``(T, 13)`` position (m), velocity (m/s, world), quaternion xyzw (body to world), body
            rates (rad/s).
        accel: ``(T, 3)`` specific force in the body frame, m/s².
        expect: the vehicle's mass, k_F and gravity.
        where: the file or flight the messages name.
        columns: the source's names of the column groups.

    Returns:
        The figures found (each group's slopes, the specific force's level, the rotors' k_F ratio).

    Raises:
        DataError: naming ``where``, the column, the factor found and the likely unit or convention.
    """
    t, u, y, accel = (np.asarray(a, dtype=float) for a in (t, u, y, accel))
    n = len(t)
    found: dict = {}
    if n < 3:
        return found
    dt = float(np.median(np.diff(t)))
    first, last = _stuck(y)
    if (last - first) * dt >= STUCK_S:
        raise DataError(f"{where}: rows {first + 1}-{last + 1} (t = {t[first]:.6g} to {t[last]:.6g} s): every output "
                        f"column holds one value for {(last - first) * dt:.3g} s; a stuck logger, not a flight "
                        "(sensor noise moves every column from sample to sample)")
    median_u = np.median(u, axis=0)
    if (median_u < 0).any():
        k = int(np.argmax(median_u < 0))
        raise DataError(f"{where}: column(s) {columns.rotors!r}: rotor {k + 1} turns at a median {median_u[k]:.4g} "
                        "rad/s; rotor speeds are magnitudes (a sign convention, or negated eRPM?)")
    g = expect.gravity
    level = float(np.median(np.linalg.norm(accel, axis=1)) / g)
    found["accel_level"] = level
    if not SLOPE_BAND[0] <= level <= SLOPE_BAND[1]:
        raise DataError(f"{where}: column(s) {columns.accel!r}: the specific force's median magnitude is {level * g:.4g} "
                        f"m/s², {_likely('accel', level)} (a flying vehicle's is about g = {g:g} m/s²)")
    rot = Rotation.from_quat(y[:, 6:10])
    world = rot.apply(accel)
    mean = world.mean(0)
    up = float(mean[2] / np.linalg.norm(mean))
    found["accel_up"] = up
    if up < 0.9:
        wfirst = Rotation.from_quat(y[:, [7, 8, 9, 6]]).apply(accel).mean(0)
        inverse = rot.inv().apply(accel).mean(0)
        cause = ("the quaternion is in w, x, y, z order" if wfirst[2] / np.linalg.norm(wfirst) > 0.9 else
                 "the quaternion turns world to body, not body to world" if inverse[2] / np.linalg.norm(inverse) > 0.9
                 else "the attitude's convention or the accelerometer's frame")
        raise DataError(f"{where}: column(s) {columns.attitude!r}: rotated to the world by the attitude, the mean "
                        f"specific force points {np.degrees(np.arccos(np.clip(up, -1, 1))):.0f}° away from up; likely "
                        f"{cause}")
    w = int(round(WINDOWS["rates"] / dt))
    s = _windows(n, w)
    if len(s) >= MIN_WINDOWS:
        turned = (rot[s].inv() * rot[s + w]).as_rotvec()
        found["rates"] = _judge("rates", columns.rates, "the attitude's change (the rotation between attitudes "
                                f"{WINDOWS['rates']:g} s apart)", _integral(y[:, 10:13], dt, s, w), turned, where)
    w = int(round(WINDOWS["velocity"] / dt))
    s = _windows(n, w)
    if len(s) >= MIN_WINDOWS:
        found["velocity"] = _judge("velocity", columns.velocity, "the specific force rotated to the world, less "
                                   f"gravity ({WINDOWS['velocity']:g} s integrals)", y[s + w, 3:6] - y[s, 3:6],
                                   _integral(world - [0.0, 0.0, g], dt, s, w), where, offset=True)
    w = int(round(WINDOWS["position"] / dt))
    s = _windows(n, w)
    if len(s) >= MIN_WINDOWS:
        vouched = bool(found.get("velocity"))  # the velocity checked against the accelerometer already
        found["position"] = _judge("position", columns.position, f"the velocity's integral ({WINDOWS['position']:g} s "
                                   "windows)", y[s + w, 0:3] - y[s, 0:3], _integral(y[:, 3:6], dt, s, w), where,
                                   other=None if vouched else ("velocity_inverse", columns.velocity))
    squares = float(np.mean(np.sum(u ** 2, axis=1)))
    # thrust k_F ΣΩ² = m |a| at every sample (drag aside), so over the flight k_F = m mean|a| / mean ΣΩ²
    k_f = expect.mass * float(np.mean(np.linalg.norm(accel, axis=1))) / squares if squares > 0 else np.inf
    ratio = k_f / expect.k_f
    found["k_f_ratio"] = float(ratio)
    if not 1 / K_F_FACTOR <= ratio <= K_F_FACTOR:
        speed = float(np.sqrt(1 / ratio)) if np.isfinite(ratio) and ratio > 0 else float("inf")
        raise DataError(f"{where}: column(s) {columns.rotors!r}: the thrust the flight needs (mass × specific force) "
                        f"asks k_F = {k_f:.3g} of these speeds, {ratio:.3g} times the vehicle's {expect.k_f:.3g}: the "
                        f"logged speeds are {_likely('rotors', speed)}")
    top = np.percentile(u, 99, axis=0)  # a glitch of a few samples is the sync's to drop, not a unit
    if (top > 1.5 * NO_LOAD_SPEED).any():
        k = int(np.argmax(top))
        raise DataError(f"{where}: column(s) {columns.rotors!r}: rotor {k + 1} turns above {top[k]:.4g} rad/s for 1 % "
                        f"of the flight, beyond the motor's no-load speed (about {NO_LOAD_SPEED:g} rad/s) by half again: "
                        "no rotor speed of this vehicle")
    return found


def check_flight(flight, expect: Expect, where: str | None = None) -> dict:
    """:func:`check` on a :class:`~nanosysid.dataio.Flight` in the published schema; ``where``
    defaults to its source file, else its name."""
    missing = [c for c in ("ax_body", "ay_body", "az_body") if c not in flight.extra]
    if missing:
        return {}
    accel = np.stack([flight.extra[c] for c in ("ax_body", "ay_body", "az_body")], axis=1)
    return check(flight.t, flight.u, flight.y, accel, expect,
                 where or str(flight.source or f"flight {flight.name}"))
