"""The four reference trajectories of the benchmark (paper, section Trajectory Design).

Each trajectory is a :class:`Reference`: position, velocity and acceleration setpoints as
vectorised functions of time (s), over ``[0, duration]``; before 0 and after the end the
setpoint holds still at the first or last point. Positions are in the world frame (m, z up);
the yaw reference is zero throughout, except in the yaw calibration flight (:func:`yaw_sweep`),
which hovers while its yaw setpoint sweeps a sine: an identification flight for the
rotors' torque coefficient k_M, not one of the benchmark's trajectories.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
from scipy.interpolate import CubicSpline

from nanosysid.errors import ConfigError

__all__ = ["Reference", "square", "random_points", "melon", "chirp", "yaw_sweep", "make_reference", "TRAJECTORIES"]

PVA = tuple[np.ndarray, np.ndarray, np.ndarray]


@dataclass(frozen=True)
class Reference:
    """A trajectory: ``pva(t) -> (p, v, a)``, each ``(len(t), 3)``, and a yaw setpoint
    ``yaw(t)`` (rad, ``(len(t),)``; zero unless ``yaw_inside`` is given)."""

    name: str
    duration: float
    pva_inside: Callable[[np.ndarray], PVA]
    yaw_inside: Callable[[np.ndarray], np.ndarray] | None = None
    # the position (m) held before t = 0 (the hover the simulator starts from); None: p(0)
    hold_before: tuple[float, float, float] | None = None

    def yaw(self, t: np.ndarray) -> np.ndarray:
        t = np.clip(np.asarray(t, dtype=np.float64), 0.0, self.duration)
        return np.zeros(len(t)) if self.yaw_inside is None else self.yaw_inside(t)

    def pva(self, t: np.ndarray) -> PVA:
        before = (np.asarray(t, dtype=np.float64) < 0.0)[:, None]
        t = np.clip(np.asarray(t, dtype=np.float64), 0.0, self.duration)
        p, v, a = self.pva_inside(t)
        if self.hold_before is not None:
            p = np.where(before, np.asarray(self.hold_before), p)
        # hold still outside the trajectory: zero velocity and acceleration setpoints
        outside = ((np.asarray(t) <= 0.0) | (np.asarray(t) >= self.duration))[:, None]
        return p, np.where(outside, 0.0, v), np.where(outside, 0.0, a)


def _min_snap_1d(tau: np.ndarray) -> PVA:
    """Rest-to-rest minimum-snap profile s(tau) on [0, 1], zero velocity, acceleration and
    jerk at both ends: s = 35 tau^4 - 84 tau^5 + 70 tau^6 - 20 tau^7."""
    s = tau**4 * (35 - 84 * tau + 70 * tau**2 - 20 * tau**3)
    ds = tau**3 * (140 - 420 * tau + 420 * tau**2 - 140 * tau**3)
    dds = tau**2 * (420 - 1680 * tau + 2100 * tau**2 - 840 * tau**3)
    return s, ds, dds


def _min_jerk_to_rest(p0: np.ndarray, v0: np.ndarray, a0: np.ndarray, p1: np.ndarray, T: float):
    """Minimum-jerk (quintic) move from (p0, v0, a0) to rest at p1 in T s, per axis."""
    # p(s) = sum c_k s^k with s in [0, T]; c0..c2 from the start, c3..c5 from the end
    c0, c1, c2 = p0, v0, a0 / 2
    d = p1 - c0 - c1 * T - c2 * T**2
    A = np.array([[T**3, T**4, T**5], [3 * T**2, 4 * T**3, 5 * T**4], [6 * T, 12 * T**2, 20 * T**3]])
    rhs = np.stack((d, -c1 - 2 * c2 * T, -2 * c2))  # (3, 3 axes)
    c3, c4, c5 = np.linalg.solve(A, rhs)

    def pva(s):
        s = s[:, None]
        p = c0 + c1 * s + c2 * s**2 + c3 * s**3 + c4 * s**4 + c5 * s**5
        v = c1 + 2 * c2 * s + 3 * c3 * s**2 + 4 * c4 * s**3 + 5 * c5 * s**4
        a = 2 * c2 + 6 * c3 * s + 12 * c4 * s**2 + 20 * c5 * s**3
        return p, v, a

    return pva


def _piecewise_moves(points: np.ndarray, move: float, hold: np.ndarray, profile) -> tuple[float, Callable]:
    """Rest-to-rest moves between consecutive ``points`` (K, 3), each lasting ``move`` s and
    followed by ``hold[k]`` s of hover."""
    starts = np.concatenate(([0.0], np.cumsum(move + hold[:-1])))  # start time of each move
    duration = float(starts[-1] + move + hold[-1])

    def pva(t):
        k = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(starts) - 1)
        tau = np.clip((t - starts[k]) / move, 0.0, 1.0)
        s, ds, dds = profile(tau)
        d = points[k + 1] - points[k]  # (N, 3)
        return (points[k] + s[:, None] * d, ds[:, None] * d / move, dds[:, None] * d / move**2)

    return duration, pva


def square(*, side: float = 1.0, z_low: float = 1.0, z_step: float = 1.0, move: float = 1.0,
           hold: float = 1.0) -> Reference:
    """Two horizontal squares of ``side`` m stacked ``z_step`` m apart, flown corner to corner.

    Every edge is a minimum-snap move of ``move`` s followed by ``hold`` s of hover; after
    the lower loop the vehicle climbs to the upper plane, repeats the loop, and returns to the
    starting height (19 s with the defaults).
    """
    h = side / 2
    corners = np.array([[-h, -h], [h, -h], [h, h], [-h, h], [-h, -h]])
    low = np.column_stack((corners, np.full(5, z_low)))
    high = np.column_stack((corners, np.full(5, z_low + z_step)))
    points = np.vstack((low, high, low[:1]))  # 11 points, 10 moves
    holds = np.full(10, hold)
    holds[-1] = 0.0  # the return to the starting height ends the flight
    duration, pva = _piecewise_moves(points, move, holds, _min_snap_1d)
    return Reference("square", duration, pva)


def random_points(*, n_points: int = 52, duration: float = 60.0, box: tuple[float, float, float] = (2.0, 2.0, 1.0),
                  center: tuple[float, float, float] = (0.0, 0.0, 1.5), seed: int = 0,
                  points: Sequence[Sequence[float]] | None = None) -> Reference:
    """``n_points`` waypoints drawn uniformly in a box (m), joined by a clamped cubic spline
    with knots evenly spaced over ``duration`` s. The seed fixes the waypoints, so runs of the
    same seed re-fly the same path. ``points`` ``(n, 3)`` (m) gives the waypoints instead (a
    logged reference's), and ``n_points``, ``box``, ``center`` and ``seed`` go unused."""
    if points is not None:
        pts = np.asarray(points, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 2:
            raise ConfigError(f"random.points: a list of at least two [x, y, z] waypoints, got shape {pts.shape}")
    else:
        rng = np.random.default_rng(seed)
        pts = np.asarray(center) + (rng.random((n_points, 3)) - 0.5) * np.asarray(box)
    knots = np.linspace(0.0, duration, len(pts))
    spline = CubicSpline(knots, pts, bc_type="clamped", axis=0)
    d1, d2 = spline.derivative(1), spline.derivative(2)
    return Reference("random", duration, lambda t: (spline(t), d1(t), d2(t)))


def melon(*, radius: float = 0.75, omega_circle: float = 2.5, omega_plane: float = 0.4,
          center: tuple[float, float, float] = (0.0, 0.0, 1.5), duration: float = 65.0,
          circle_time: float = 55.0, ramp_time: float = 1.0, return_time: float = 4.0,
          omega_start: float | None = None, start_from_centre: bool = False,
          start_height: float | None = None) -> Reference:
    """Circles of ``radius`` m in a local x-z plane, the plane turning about the world x axis at
    ``omega_plane`` rad/s, for ``circle_time`` s; then a minimum-jerk return to the centre over
    ``return_time`` s, and hover there until ``duration``. The circling rate rises linearly from
    ``omega_start`` rad/s at the start to ``omega_circle`` at ``circle_time`` (None: constant at
    ``omega_circle``), and the whole of it is ramped in linearly over the first ``ramp_time`` s.
    With ``start_from_centre`` the vehicle hovers at the centre before the start and the setpoint
    jumps onto the circle at t = 0 (the rig's logged Melon); otherwise it starts on the circle.
    ``start_height`` (m) puts that hover below or above the centre (None: at its height).
    """
    c = np.asarray(center)
    if circle_time + return_time > duration:
        raise ValueError(f"melon: circle_time + return_time = {circle_time + return_time} s exceeds duration {duration} s")
    if omega_start is not None and circle_time <= 0:
        raise ValueError(f"melon: a circling rate rising from omega_start needs circle_time > 0, got {circle_time}")
    r, wc, wp, Tr = radius, omega_circle, omega_plane, ramp_time
    w0 = wc if omega_start is None else omega_start
    k = 0.0 if omega_start is None else (wc - w0) / circle_time  # rad/s², the circling rate's rise

    def circle(t):
        # circle phase th(t): the rate w0 + k t, times t / Tr over the first Tr s
        ramp, span = t < Tr, max(Tr, 1e-9)
        th = np.where(ramp, (0.5 * w0 * t**2 + k * t**3 / 3) / span, w0 * (t - 0.5 * Tr) + k * (0.5 * t**2 - Tr**2 / 6))
        dth = np.where(ramp, (w0 * t + k * t**2) / span, w0 + k * t)
        ddth = np.where(ramp, (w0 + 2 * k * t) / span, k)
        ct, st = np.cos(th), np.sin(th)
        cp, sp = np.cos(wp * t), np.sin(wp * t)
        # local point (r cos th, 0, r sin th) rotated about x by wp t
        p = np.column_stack((r * ct, -r * st * sp, r * st * cp))
        # d/dt of (st sp) and (st cp), and their second derivatives
        d_stsp = dth * ct * sp + wp * st * cp
        d_stcp = dth * ct * cp - wp * st * sp
        dd_stsp = (ddth * ct - dth**2 * st) * sp + 2 * dth * wp * ct * cp - wp**2 * st * sp
        dd_stcp = (ddth * ct - dth**2 * st) * cp - 2 * dth * wp * ct * sp - wp**2 * st * cp
        v = np.column_stack((-r * dth * st, -r * d_stsp, r * d_stcp))
        a = np.column_stack((-r * (ddth * st + dth**2 * ct), -r * dd_stsp, r * dd_stcp))
        return p, v, a

    end = [x[0] for x in circle(np.array([circle_time]))]
    back_pva = _min_jerk_to_rest(*end, np.zeros(3), return_time)

    def pva(t):
        p, v, a = circle(np.minimum(t, circle_time))
        back = t > circle_time
        if back.any():
            p[back], v[back], a[back] = back_pva(np.minimum(t[back] - circle_time, return_time))
        return p + c, v, a

    hold = (c[0], c[1], c[2] if start_height is None else start_height)
    return Reference("melon", duration, pva, hold_before=tuple(float(x) for x in hold) if start_from_centre else None)


def chirp(*, amplitude: float = 0.5, f_start: float = 0.1, f_end: float = 0.5, duration: float = 60.0,
          center: tuple[float, float, float] = (0.0, 0.0, 1.5)) -> Reference:
    """Each axis ``c - A cos(phi(t))`` with the frequency rising linearly from ``f_start`` to
    ``f_end`` Hz over ``duration`` s. The cosine form starts and, with the defaults, ends at
    rest (phi(60 s) is a whole number of turns)."""
    c = np.asarray(center)
    A, k = amplitude, (f_end - f_start) / duration

    def pva(t):
        phi = 2 * np.pi * (f_start * t + 0.5 * k * t**2)
        dphi = 2 * np.pi * (f_start + k * t)
        ddphi = 2 * np.pi * k
        cos, sin = np.cos(phi), np.sin(phi)
        p = c - A * cos[:, None] * np.ones(3)
        v = (A * sin * dphi)[:, None] * np.ones(3)
        a = (A * (cos * dphi**2 + sin * ddphi))[:, None] * np.ones(3)
        return p, v, a

    return Reference("chirp", duration, pva)


def yaw_sweep(*, amplitude: float = 0.2, f_low: float = 0.05, f_high: float = 1.0, duration: float = 60.0,
              fade: float = 3.0, center: tuple[float, float, float] = (0.0, 0.0, 1.5)) -> Reference:
    """Hover at ``center`` while the yaw setpoint sweeps a sine of ``amplitude`` rad from
    ``f_low`` to ``f_high`` Hz, its frequency rising linearly over ``duration`` s, faded in and
    out over ``fade`` s (a half cosine). The excitation the yaw loop's own disturbance
    rejection cannot supply: an exogenous signal, the instrument of the k_M fit
    (:mod:`nanosysid.identify`). A linear sweep spends most of its time at the higher
    frequencies, where the torque it asks for (growing with the square of the frequency) stands
    out of the slow yaw disturbances."""
    k = (f_high - f_low) / duration

    def yaw(t):
        ramp = np.clip(np.minimum(t, duration - t) / fade, 0.0, 1.0)
        return amplitude * np.sin(2 * np.pi * (f_low * t + 0.5 * k * t**2)) * 0.5 * (1 - np.cos(np.pi * ramp))

    c = np.asarray(center, dtype=np.float64)

    def pva(t):
        n = len(t)
        return np.tile(c, (n, 1)), np.zeros((n, 3)), np.zeros((n, 3))

    return Reference("yawsweep", duration, pva, yaw)


TRAJECTORIES = {"square": square, "random": random_points, "melon": melon, "chirp": chirp, "yawsweep": yaw_sweep}


def make_reference(name: str, **options) -> Reference:
    """A trajectory by name with its options (the keys of ``conf/sim``'s trajectory blocks)."""
    try:
        return TRAJECTORIES[name](**options)
    except KeyError:
        raise KeyError(f"unknown trajectory {name!r}; known: {', '.join(TRAJECTORIES)}") from None
