"""Knowledge: named physical effects from the literature that the nominal model leaves out.

These are hypotheses, not the simulator's world (that is :mod:`nanosysid.sim.world`, which
this module never imports): discovery searches them, the augmented model adds the ones it
names, and the export writes them out in C. Where the literature has several forms of one
effect (drag linear in the body velocity, proportional to the rotor speeds times it, or
quadratic), each form is its own entry, and discovery says when the data cannot tell them
apart. Each effect is written once, as the columns of a linear model of the extra body wrench,

    ``[F_B; tau_B] = Phi(x, Omega, dOmega/dt) theta``,  ``Phi`` of shape ``(6, P)``,

over component scalars (:class:`Signals`). The same function gives the regression's feature
columns and the augmented model's batched torch wrench (:func:`features`, over tensors), and
the generated C (:func:`wrench`, over the C generator's traced scalars).

Three kinds of entry:

- ``wrench``: an extra body force and torque, added to the rigid body's equations;
- ``correction``: a correction of a nominal parameter (inertia, arm; k_F and k_M are refitted
  with every candidate). In the regression its columns are the first-order change of the
  residual, written with the model's own rotor torques; the augmented model applies it to the
  vehicle. The mass is no candidate: every force the model predicts is divided by it, and the
  accelerometer sees only force over mass, which k_F's refit already carries;
- ``delay``: ``input_delay``, a delay of the recorded rotor speeds, found by search.

Besides the named entries, :func:`entry` builds *generic terms*, ``term:<channel>:<a>*<b>``:
one product of the physically meaningful signals of :data:`TERM_SIGNALS` on one channel,
the vocabulary of the sparse fit that captures a disagreement no named effect explains.

Rotor layout and spin directions are :mod:`nanosysid.dynamics`'.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np
import torch
from torch import Tensor

from nanosysid import so3
from nanosysid.dynamics import ROTOR_X, ROTOR_Y, SPIN, signed_sum
from nanosysid.vehicle import Vehicle

__all__ = ["CHANNELS", "Signals", "Effect", "LIBRARY", "NOMINAL", "DELAY", "TERM_SIGNALS", "signals", "features",
           "wrench", "split_coefficients", "entry", "term_name", "apply_corrections", "refitted_vehicle", "SLOW_TIMES",
           "lag_in_k_f", "lagged_k_f",
           "INERTIA_SHARE", "GROUND_EFFECT",
           "VBAT_REF", "slow_squares"]

CHANNELS = ("F_x", "F_y", "F_z", "tau_x", "tau_y", "tau_z")


@dataclass(frozen=True)
class Signals:
    """What an effect's columns are made of, component by component: each a float, a tensor
    ``(...,)`` or a traced scalar of the C generator.

    Attributes:
        v: Air velocity in the body frame (still air): ``R^T v`` (m/s), 3 components.
        w: Body rates (rad/s), 3.
        om: Rotor speeds (rad/s), 4; ``s`` their squares; ``om_dot`` their rates (rad/s^2).
        z: Height (m) above the floor, the position's z.
        s_slow: The squares' history: each rotor's ``Omega_i^2`` through a first-order low-pass of
            each time constant of :data:`SLOW_TIMES`, ``4 * len(SLOW_TIMES)`` components (time
            constant major); empty where the history is not given (the entries that need it
            then add nothing).
        vbat: Battery voltage (V); None where not measured.
        lag_in_k_f: Per time constant of :data:`SLOW_TIMES`, the share ``c_k`` of a lag that
            least squares of the thrust on the squares takes into k_F (:func:`lag_in_k_f`):
            given such a k_F, the slow actuation's columns are written relative to it; empty
            where k_F is the rotors' own (the augmented model's, :func:`lagged_k_f`).
    """

    v: Sequence[Any]
    w: Sequence[Any]
    om: Sequence[Any]
    s: Sequence[Any]
    om_dot: Sequence[Any]
    z: Any
    s_slow: Sequence[Any] = ()
    vbat: Any = None
    lag_in_k_f: Sequence[float] = ()


Columns = Callable[[Signals, Vehicle], list[list[Any]]]


@dataclass(frozen=True)
class Effect:
    """One entry of the library.

    Attributes:
        name: The effect's name.
        description: What it is, physically, with its source.
        params: Names of its coefficients, with units.
        columns: ``(Signals, vehicle) -> 6 rows of P entries`` (0.0 where a channel is untouched);
            None for the nonlinear ``input_delay``.
        touches: The benchmark quantities it acts on directly.
        signs: Per coefficient, +1 where physics fixes its sign (a drag coefficient is positive),
            0 where either sign is possible.
        kind: ``"wrench"``, ``"correction"`` or ``"delay"``.
        excited_by: The manoeuvre that shows this effect apart from others (said when the data
            cannot tell it from another entry).
        needs: What its columns read beyond the state and the rotor speeds: ``"history"`` (the
            rotor speeds' past, :attr:`Signals.s_slow`), ``"vbat"`` (the battery voltage).
    """

    name: str
    description: str
    params: tuple[str, ...]
    columns: Columns | None
    touches: tuple[str, ...]
    signs: tuple[int, ...] = ()
    kind: str = "wrench"
    excited_by: str = ""
    physical: Callable[[Sequence[float], Vehicle], list[float]] | None = None
    # the largest share of the nominal value a correction (or a relative coefficient) may have;
    # beyond it the fit is not correcting a parameter but soaking up something else (a
    # disturbance the controller fights correlates with every column proportional to the rotor
    # torque)
    bound: float | None = None
    # number of columns where it differs from the number of physical parameters (``physical``
    # maps the columns' coefficients to them)
    width: int | None = None
    needs: tuple[str, ...] = ()
    # the shape physics gives the coefficients together, beyond each one's sign: values ->
    # whether they make the effect (a lag's step response rises and never falls back)
    shape: Callable[[Sequence[float]], bool] | None = None

    @property
    def n_columns(self) -> int:
        """Number of columns (coefficients in the regression and the augmented model)."""
        return self.width if self.width is not None else len(self.params)

    def nominal(self, vehicle: Vehicle) -> list[float]:
        """The values :attr:`bound` is a share of: a correction's nominal values, 1 for a
        relative coefficient."""
        return {"inertia": list(vehicle.inertia), "arm": [vehicle.arm],
                "ground_effect": [GROUND_EFFECT]}.get(self.name, [1.0] * len(self.params))

    def values(self, theta: Sequence[float], vehicle: Vehicle) -> list[float]:
        """The coefficients of the columns as the physical parameters :attr:`params` name."""
        return [float(t) for t in theta] if self.physical is None else self.physical(theta, vehicle)

    def implausible(self, theta: Sequence[float], vehicle: Vehicle, half_width: Sequence[float] | None = None, *,
                    shape: bool = True) -> str:
        """Why the columns' coefficients ``theta`` cannot be this effect, by its own rules: a
        coefficient whose sign physics fixes lies below zero by more than its interval's
        ``half_width`` (judged only where the half-widths are given); or its values break
        :meth:`implausible_values`. An empty string where none applies."""
        if half_width is not None:
            low = [p for p, s, m, h in zip(self.params, self.signs, theta, half_width) if s > 0 and m < -h]
            if low:
                return f"{', '.join(p.split(' [')[0] for p in low)} below zero, against its physical sign"
        return self.implausible_values(self.values(theta, vehicle), vehicle, shape=shape)

    def implausible_values(self, values: Sequence[float], vehicle: Vehicle, *, shape: bool = True) -> str:
        """Why the physical parameters ``values`` (:attr:`params`) cannot be this effect: a value
        beyond :attr:`bound` of its nominal (a lag's share of the rotors' wrench beyond 1 is a
        band-pass of the rotor speeds, which fits the controller's answer to any slow torque, not
        a lag); or, with ``shape``, values without the :attr:`shape` physics gives them together.
        An empty string where neither applies."""
        if self.bound is not None:
            over = [p for p, x, n in zip(self.params, values, self.nominal(vehicle))
                    if not np.isfinite(x) or abs(x) > self.bound * abs(n)]
            if over:
                return f"{', '.join(p.split(' [')[0] for p in over)} beyond the entry's bound ({self.bound:g})"
        if shape and self.shape is not None and not self.shape(values):
            return "its coefficients do not have the shape physics gives them together"
        return ""


# m²: Cheeseman and Bennett's ground effect c = (R / 4)² for the 27.5 mm rotor radius of
# drone-models' cf21B; a multirotor's rotors near the floor add to each other's: gym-pybullet-drones
# fits 11.4 times it for the Crazyflie 2.x. A fit beyond GROUND_EFFECT_BOUND times it is a
# disagreement that follows the height, not the floor's
GROUND_EFFECT = (0.0275 / 4) ** 2
GROUND_EFFECT_BOUND = 25.0


# the body's inertia an inertia correction may give, as shares of the nominal: a fit outside
# (a fold's few flights telling little of the yaw) is held at the nearer end
INERTIA_SHARE = (0.2, 5.0)


def _inertia_change(theta: Sequence[float], vehicle: Vehicle) -> list[float]:
    """``dJ`` (kg m², per body axis) from the acceleration columns' coefficients ``c = dJ J / (J +
    dJ)`` (the true body turns ``J / (J + dJ)`` as fast as the nominal model says), ``J + dJ``
    held within :data:`INERTIA_SHARE` of ``J``."""
    lo, hi = INERTIA_SHARE
    return [float(c * j / (j - c)) for c, j in
            ((float(np.clip(c, j * (1 - 1 / lo), j * (1 - 1 / hi))), j) for c, j in zip(theta, vehicle.inertia))]


def _zero_rows(P: int) -> list[list[Any]]:
    return [[0.0] * P for _ in range(6)]


def _sum(values: Sequence[Any]) -> Any:
    return signed_sum((1.0,) * len(values), values)


def _drag(speed_weight: Callable[[Signals, int], Any]) -> Columns:
    """Drag ``F = -diag(a, a, b) g(v) `` with ``g`` per axis: columns (a, b)."""

    def columns(sg: Signals, vehicle: Vehicle) -> list[list[Any]]:
        rows = _zero_rows(2)
        rows[0][0] = -speed_weight(sg, 0)
        rows[1][0] = -speed_weight(sg, 1)
        rows[2][1] = -speed_weight(sg, 2)
        return rows

    return columns


def _drag_moment(weight: Callable[[Signals], Any], per_axis: bool = False) -> Columns:
    """Torque of a horizontal drag ``-D v`` acting a height ``h`` above the centre of mass:
    ``(0, 0, h) x F = h D (v_y, -v_x, 0)``, one column, coefficient ``h D``; ``per_axis``: one
    column per roll and pitch axis, ``(h D)_x`` and ``(h D)_y``."""

    def columns(sg: Signals, vehicle: Vehicle) -> list[list[Any]]:
        k = weight(sg)
        rows = _zero_rows(2 if per_axis else 1)
        rows[3][0] = sg.v[1] if k is None else k * sg.v[1]
        rows[4][1 if per_axis else 0] = -sg.v[0] if k is None else -(k * sg.v[0])
        return rows

    return columns


def _rate_damping(weight: Callable[[Signals], Any]) -> Columns:
    def columns(sg: Signals, vehicle: Vehicle) -> list[list[Any]]:
        k = weight(sg)
        rows = _zero_rows(2)
        rows[3][0] = -sg.w[0] if k is None else -(k * sg.w[0])
        rows[4][0] = -sg.w[1] if k is None else -(k * sg.w[1])
        rows[5][1] = -sg.w[2] if k is None else -(k * sg.w[2])
        return rows

    return columns


def _inflow(sg: Signals, vehicle: Vehicle) -> list[list[Any]]:
    rows = _zero_rows(1)
    rows[2][0] = -(vehicle.k_f * _sum(sg.s) * sg.v[2])
    return rows


def _ground_effect(sg: Signals, vehicle: Vehicle) -> list[list[Any]]:
    rows = _zero_rows(1)
    rows[2][0] = vehicle.k_f * _sum(sg.s) / (sg.z * sg.z)
    return rows


def _cg_offset(sg: Signals, vehicle: Vehicle) -> list[list[Any]]:
    thrust = vehicle.k_f * _sum(sg.s)
    rows = _zero_rows(2)
    # torque of the thrust (0, 0, T) about a centre of mass at (r_x, r_y, 0): T (-r_y, r_x, 0)
    rows[4][0] = thrust
    rows[3][1] = -thrust
    return rows


# the zero-mean patterns of four rotors' spread: roll, pitch and yaw pairs (orthogonal). The
# common mode, every rotor off by the same share, is the refitted k_F and k_M and the arm.
SPREAD_MODES = (ROTOR_Y, ROTOR_X, SPIN)


def _rotor_spread(sg: Signals, vehicle: Vehicle) -> list[list[Any]]:
    # rotor i with k_F (1 + d_i) and k_M (1 + d_i) adds d_i times its own column of the mixer;
    # d = sum_j a_j SPREAD_MODES[j], one column per mode
    kl = vehicle.k_f * vehicle.arm
    per_rotor = [[vehicle.k_f * sg.s[i] for i in range(4)], [(kl * ROTOR_Y[i]) * sg.s[i] for i in range(4)],
                 [(-kl * ROTOR_X[i]) * sg.s[i] for i in range(4)], [(-vehicle.k_m * SPIN[i]) * sg.s[i] for i in range(4)]]
    rows = _zero_rows(3)
    for j, mode in enumerate(SPREAD_MODES):
        for r, row in zip((2, 3, 4, 5), per_rotor):
            rows[r][j] = signed_sum(mode, row)
    return rows


def _spread_values(theta: Sequence[float], vehicle: Vehicle) -> list[float]:
    return [float(sum(a * m[i] for a, m in zip(theta, SPREAD_MODES))) for i in range(4)]


def _rotor_gyro(sg: Signals, vehicle: Vehicle) -> list[list[Any]]:
    h = signed_sum(SPIN, sg.om)  # rotor angular momentum along body z, per unit rotor inertia
    rows = _zero_rows(1)
    # gyroscopic torque -w x (0, 0, J_r h) and the reaction to spinning the rotors up
    rows[3][0] = -(sg.w[1] * h)
    rows[4][0] = sg.w[0] * h
    rows[5][0] = -signed_sum(SPIN, sg.om_dot)
    return rows


# Time constants (s) of the rotor-speed history the slow actuation is written over: a kernel of
# three exponentials spans the band the paper reports its unexplained torque in (0.4-1.2 Hz)
SLOW_TIMES = (0.1, 0.3, 1.0)
# Battery voltage (V) at which the refitted k_F holds: a 1S LiPo's mid charge
VBAT_REF = 3.7


def _rotor_wrench_rows(vehicle: Vehicle, per_rotor: Sequence[Any]) -> tuple[Any, Any, Any, Any]:
    """Thrust and roll/pitch/yaw torques of the quadratic rotor model applied to ``per_rotor``
    in place of the squares."""
    kl = vehicle.k_f * vehicle.arm
    return (vehicle.k_f * _sum(per_rotor), kl * signed_sum(ROTOR_Y, per_rotor),
            kl * signed_sum([-x for x in ROTOR_X], per_rotor), vehicle.k_m * signed_sum([-c for c in SPIN], per_rotor))


def _slow_actuation(sg: Signals, vehicle: Vehicle) -> list[list[Any]]:
    # rotor i gives k (Omega_i^2 + sum_k g_k (LP_k(Omega_i^2) - Omega_i^2)): part of its thrust and
    # drag torque follows the measured speed through a lag of time constant T_k. A k_F fitted by
    # least squares without the lag is k (1 + sum_k g_k c_k): to first order in the shares, the
    # thrust and the roll/pitch torques are k_F (Omega_i^2 + sum_k g_k (LP_k - (1 + c_k) Omega_i^2))
    # (k_M comes from a yaw sweep, whose share of the lag is its own)
    rows = _zero_rows(len(SLOW_TIMES))
    if not sg.s_slow:
        return rows
    for k in range(len(SLOW_TIMES)):
        lag = [sg.s_slow[4 * k + i] - sg.s[i] for i in range(4)]
        rotors = _rotor_wrench_rows(vehicle, lag)
        if sg.lag_in_k_f:
            c = float(sg.lag_in_k_f[k])
            rotors = (*_rotor_wrench_rows(vehicle, [x - c * s for x, s in zip(lag, sg.s)])[:3], rotors[3])
        for r, value in zip((2, 3, 4, 5), rotors):
            rows[r][k] = value
    return rows


def lag_in_k_f(oms: Sequence[np.ndarray], dt: float) -> tuple[float, ...]:
    """Per time constant of :data:`SLOW_TIMES`, the share ``c_k`` of a slow actuation's lag that
    least squares of the thrust on the squares, ``m a_z = k_F Σ Ω_i²`` without an intercept (the
    identify stage's k_F), takes into k_F over flights of rotor speeds ``oms`` (each ``(T, 4)``
    rad/s, sampled every ``dt`` s): with the thrust ``k (S + Σ_k g_k (LP_k(S) - S))``, ``S = Σ Ω_i²``,
    that fit gives ``k (1 + Σ_k g_k c_k)``, ``c_k = <S, LP_k(S) - S> / <S, S>`` (below zero: a lag
    takes the fluctuations' share off)."""
    num, den = np.zeros(len(SLOW_TIMES)), 0.0
    for om in oms:
        om = torch.as_tensor(np.asarray(om, dtype=float))
        total = (om * om).sum(-1).numpy()
        slow = slow_squares(om[None], dt)[0].numpy().reshape(len(om), len(SLOW_TIMES), 4).sum(-1)
        num += total @ (slow - total[:, None])
        den += float(total @ total)
    return tuple(float(x) for x in num / den)


def lagged_k_f(k_f: float, shares: Sequence[float], lag: Sequence[float]) -> float:
    """The rotors' own k_F (N s²/rad²) under a slow actuation of ``shares``, from a k_F fitted by
    least squares without it that took ``lag`` (:func:`lag_in_k_f`) of each lag: to first order,
    ``k_F (1 - Σ_k g_k c_k)``."""
    return float(k_f * (1.0 - float(np.dot(shares, lag))))


# the most a slow actuation's step response may fall back, as a share of its rise: shares of
# either sign may come out of a fit (a small negative share beside the lag's own), but a
# response that rises and then falls by a good part of its rise is a band-pass, which no lag of
# a rotor's wrench makes
LAG_FALL = 0.25


def lag_shape(g: Sequence[float], times: Sequence[float] = SLOW_TIMES) -> tuple[float, float]:
    """The rise and the largest fall back of the rotors' wrench after a unit step of its
    ``k Ω²``, ``1 - Σ g_k exp(-t / T_k)`` with shares ``g`` lagging through ``times`` (s), over
    five times the slowest lag: ``(rise, fall)``, the rise from its start to its highest."""
    t = np.linspace(0.0, 5.0 * max(times), 2001)
    r = 1.0 - sum(gk * np.exp(-t / tk) for gk, tk in zip(g, times))
    peak = np.maximum.accumulate(r)
    return float(peak[-1] - r[0]), float((peak - r).max())


def _is_lag(g: Sequence[float]) -> bool:
    rise, fall = lag_shape(g)
    return fall <= LAG_FALL * rise


def _battery(sg: Signals, vehicle: Vehicle) -> list[list[Any]]:
    # k_F and k_M (1 + c (V - V_ref)): the rotors' whole wrench scales with the voltage
    rows = _zero_rows(1)
    if sg.vbat is None:
        return rows
    dv = sg.vbat - VBAT_REF
    for r, value in zip((2, 3, 4, 5), _rotor_wrench_rows(vehicle, sg.s)):
        rows[r][0] = dv * value
    return rows


def _nominal(sg: Signals, vehicle: Vehicle) -> list[list[Any]]:
    """Corrections of the nominal coefficients: k_F on the thrust and k_M on the yaw torque. The
    roll/pitch torques' scale k_F L is the ``arm`` correction's: refitted with the thrust, a
    disturbance torque the controller fights would bend k_F away from what the thrust says."""
    rows = _zero_rows(2)
    rows[2][0] = _sum(sg.s)
    rows[5][1] = signed_sum([-s for s in SPIN], sg.s)
    return rows


def _inertia(sg: Signals, vehicle: Vehicle) -> list[list[Any]]:
    # the measured torque is J dw/dt + w x Jw with the nominal J; with the true J + dJ the rotors'
    # torque tau gives dw/dt = (J + dJ)^-1 (tau - w x (J + dJ) w). To first order in dJ the
    # residual is -dJ_k a_k e_k - w x (dJ_k w_k e_k) per axis k, a = J^-1 (tau - w x Jw) the
    # angular acceleration the nominal model predicts (never the measured one, which would let
    # the fit copy the measurement)
    J = vehicle.inertia
    kl = vehicle.k_f * vehicle.arm
    w = sg.w
    gyro = (w[1] * (J[2] * w[2]) - w[2] * (J[1] * w[1]), w[2] * (J[0] * w[0]) - w[0] * (J[2] * w[2]),
            w[0] * (J[1] * w[1]) - w[1] * (J[0] * w[0]))
    tau = (kl * signed_sum(ROTOR_Y, sg.s), kl * signed_sum([-x for x in ROTOR_X], sg.s),
           vehicle.k_m * signed_sum([-c for c in SPIN], sg.s))
    a = [(tau[k] - gyro[k]) * (1.0 / J[k]) for k in range(3)]
    rows = _zero_rows(3)
    # w x (w_k e_k): k = x -> (0, w_z w_x, -w_y w_x); y -> (-w_z w_y, 0, w_x w_y); z -> (w_y w_z, -w_x w_z, 0)
    rows[3][0], rows[4][0], rows[5][0] = -a[0], -(w[2] * w[0]), w[1] * w[0]
    rows[3][1], rows[4][1], rows[5][1] = w[2] * w[1], -a[1], -(w[0] * w[1])
    rows[3][2], rows[4][2], rows[5][2] = -(w[1] * w[2]), w[0] * w[2], -a[2]
    return rows


def _arm(sg: Signals, vehicle: Vehicle) -> list[list[Any]]:
    rows = _zero_rows(1)
    rows[3][0] = vehicle.k_f * signed_sum(ROTOR_Y, sg.s)
    rows[4][0] = vehicle.k_f * signed_sum([-x for x in ROTOR_X], sg.s)
    return rows


NOMINAL = Effect("nominal", "the quadratic rotor model's thrust and yaw coefficients, refitted alongside",
                 ("dk_F [N s²/rad²]", "dk_M [N m s²/rad²]"), _nominal, ("p", "v", "R", "w"), (0, 0))

DELAY = Effect("input_delay", "the recorded rotor speeds lag the true ones by a delay (telemetry over a radio link)",
               ("delay [s]",), None, ("p", "v", "R", "w"), (1,), "delay",
               "quick throttle steps: the response leads the recorded rotor speeds")

_SUM_OM = lambda sg, *_: _sum(sg.om)  # noqa: E731

LIBRARY: dict[str, Effect] = {e.name: e for e in (
    Effect("linear_drag", "rotor drag linear in the body velocity: F_B = -diag(D_xy, D_xy, D_z) v_B "
           "(Faessler, Franchi, Scaramuzza 2018)", ("D_xy [kg/s]", "D_z [kg/s]"),
           _drag(lambda sg, i: sg.v[i]), ("p", "v"), (1, 1),
           excited_by="flight at one speed and several throttles (the drag of this form does not change with them)"),
    Effect("induced_drag", "blade flapping and induced drag, linear in the rotor speeds and the body velocity: "
           "F_B = -(Σ Ω_i) diag(K_xy, K_xy, K_z) v_B (Förster's Crazyflie 2 identification)",
           ("K_xy [kg/rad]", "K_z [kg/rad]"), _drag(lambda sg, i: _sum(sg.om) * sg.v[i]), ("p", "v"), (1, 1),
           excited_by="flight at one speed and several throttles (climbing and descending turns)"),
    Effect("quadratic_drag", "quadratic airframe drag: F_B = -diag(c_xy, c_xy, c_z) |v_B| v_B",
           ("c_xy [kg/m]", "c_z [kg/m]"), _drag(lambda sg, i: abs(sg.v[i]) * sg.v[i]), ("p", "v"), (1, 1),
           excited_by="flight at several speeds: slow and fast passes of the same path"),
    Effect("inflow_thrust_loss", "thrust falling with the rotors' axial inflow (momentum theory, linearised): "
           "F_z = -k_v T v_z, T = k_F Σ Ω_i² (Hoffmann et al. 2007)", ("k_v [s/m]",), _inflow, ("p", "v"), (1,),
           excited_by="climbs and descents at several throttles"),
    Effect("ground_effect", "thrust rising near the floor (Cheeseman and Bennett): F_z = c T / z², "
           "c = (rotor radius / 4)²", ("c [m²]",), _ground_effect, ("p", "v"), (1,),
           excited_by="hover at several heights below a few rotor diameters", bound=GROUND_EFFECT_BOUND),
    Effect("drag_moment", "horizontal drag acting above or below the centre of mass: "
           "tau = h D (v_y, -v_x, 0) (the airframe's centre of pressure)", ("hD [kg m/s]",),
           _drag_moment(lambda sg: None), ("R", "w"), (0,),
           excited_by="fast straight passes at several throttles"),
    Effect("induced_drag_moment", "rotor drag and blade flapping acting at the rotor plane, off the centre of mass: "
           "tau = (Σ Ω_i) (e_x v_y, -e_y v_x, 0) (Förster's drag at the hub height; the discs flapping back from "
           "their air speed tilt the thrust, Mahony, Kumar and Corke 2012; per axis, as the airframe, the battery "
           "and the decks are longer than wide)", ("e_x [kg m/rad]", "e_y [kg m/rad]"),
           _drag_moment(lambda sg: _sum(sg.om), per_axis=True), ("R", "w"), (0, 0),
           excited_by="fast straight passes at several throttles"),
    Effect("rate_damping", "aerodynamic damping of the body rates: tau = -diag(b_xy, b_xy, b_z) ω",
           ("b_xy [N m s]", "b_z [N m s]"), _rate_damping(lambda sg: None), ("R", "w"), (1, 1),
           excited_by="fast roll, pitch and yaw rates at several throttles"),
    Effect("induced_rate_damping", "rate damping from blade flapping, growing with the rotor speeds: "
           "tau = -(Σ Ω_i) diag(b_xy, b_xy, b_z) ω", ("b_xy [kg m² /rad]", "b_z [kg m² /rad]"),
           _rate_damping(_SUM_OM), ("R", "w"), (1, 1),
           excited_by="fast body rates at several throttles"),
    DELAY,
    Effect("cg_offset", "centre of gravity at (r_x, r_y) off the rotors' centre: the thrust torques roll and pitch, "
           "tau = T (-r_y, r_x, 0)", ("r_x [m]", "r_y [m]"), _cg_offset, ("R", "w"), (0, 0),
           excited_by="throttle steps at level attitude: the torque follows the collective thrust"),
    Effect("rotor_spread", "rotors of unequal coefficients k_F (1 + d_i), k_M (1 + d_i) (manufacturing spread, wear); "
           "the d_i average zero (their mean is in the refitted k_F and k_M)",
           ("d_1 [-]", "d_2 [-]", "d_3 [-]", "d_4 [-]"), _rotor_spread, ("p", "v", "R", "w"), (0, 0, 0),
           excited_by="yaw manoeuvres, which spin the two rotor pairs at different speeds",
           physical=_spread_values, bound=0.25, width=3),
    Effect("rotor_gyro", "rotor inertia J_r: gyroscopic torque -ω × (0, 0, J_r Σ s_i Ω_i) and yaw reaction "
           "-J_r Σ s_i dΩ_i/dt", ("J_r [kg m²]",), _rotor_gyro, ("R", "w"), (1,),
           excited_by="quick yaw-rate changes and roll/pitch rates during yaw"),
    Effect("slow_actuation", "slow actuation dynamics: part of each rotor's thrust and drag torque follows k Ω_i² "
           "through first-order lags, k (Ω_i² + Σ_k g_k (LP_{T_k}(Ω_i²) - Ω_i²)), T_k = "
           + ", ".join(f"{t:g}" for t in SLOW_TIMES) + " s (the benchmark paper's hypothesis for its low-frequency "
           "roll/pitch torque; a rotor's thrust lagging its speed: Bangura and Mahony 2012, unsteady inflow "
           "of small rotors)", tuple(f"g_{t:g}s [-]" for t in SLOW_TIMES), _slow_actuation,
           ("p", "v", "R", "w"), (0,) * len(SLOW_TIMES),
           excited_by="throttle and attitude steps held for longer than the lag (a square's corners), flown twice: "
           "the lag repeats with the reference, a disturbance does not", bound=1.0, needs=("history",), shape=_is_lag),
    Effect("battery_thrust", "thrust and drag torque scaling with the battery voltage, k (1 + c (V - 3.7 V)) "
           "(Bitcraze: 'Keeping thrust consistent as the battery drains', 2025; the firmware's compensation "
           "filters the voltage with τ = 0.1 s and saturates below about 3.13 V)", ("c [1/V]",), _battery,
           ("p", "v", "R", "w"), (0,), excited_by="long flights that drain the battery: the same manoeuvre early "
           "and late", needs=("vbat",)),
    Effect("inertia", "the body's inertia off its nominal diagonal: J + diag(dJ)",
           ("dJ_x [kg m²]", "dJ_y [kg m²]", "dJ_z [kg m²]"), _inertia, ("R", "w"), (0, 0, 0), "correction",
           "roll and pitch rates during fast yaw: only the inertia has the gyroscopic w x J w",
           _inertia_change,
           # published values for this airframe class lie up to 83 % above the nominal (yaw)
           1.0),
    Effect("arm", "the rotors' lever arm off its nominal value: L + dL", ("dL [m]",), _arm, ("R", "w"), (0,),
           "correction", "roll/pitch torque without angular acceleration (holding a tilt against a wind)", None,
           # the arm is geometry, measured to a few millimetres (the centre of each rotor's thrust)
           0.1),
)}

# Physically meaningful signals of the generic terms: name -> (unit, extractor). The rotor-speed
# sum is left out: over a flight it moves with the thrust almost in proportion, and the sparse
# fit cannot choose between nearly collinear terms.
TERM_SIGNALS: dict[str, tuple[str, Callable[[Signals, Vehicle], Any]]] = {
    "v_x": ("m/s", lambda sg, vh: sg.v[0]), "v_y": ("m/s", lambda sg, vh: sg.v[1]),
    "v_z": ("m/s", lambda sg, vh: sg.v[2]),
    "w_x": ("rad/s", lambda sg, vh: sg.w[0]), "w_y": ("rad/s", lambda sg, vh: sg.w[1]),
    "w_z": ("rad/s", lambda sg, vh: sg.w[2]),
    "T": ("N", lambda sg, vh: vh.k_f * _sum(sg.s)),
    "z": ("m", lambda sg, vh: sg.z),
}
TERM_PREFIX = "term"


def term_name(channel: str, product: str) -> str:
    """The library name of a generic term: ``term:<channel>:<product>``."""
    return f"{TERM_PREFIX}:{channel}:{product}"


def _term(name: str) -> Effect:
    try:
        _, channel, product = name.split(":")
        c = CHANNELS.index(channel)
        factors = [] if product == "1" else product.split("*")
        for f in factors:
            TERM_SIGNALS[f]
    except (ValueError, KeyError):
        raise KeyError(f"no effect {name!r}: a generic term is term:<channel>:<signal>[*<signal>...], channels "
                       f"{', '.join(CHANNELS)}, signals {', '.join(TERM_SIGNALS)}") from None

    def columns(sg: Signals, vehicle: Vehicle) -> list[list[Any]]:
        value: Any = 1.0
        for f in factors:
            x = TERM_SIGNALS[f][1](sg, vehicle)
            value = x if isinstance(value, float) and value == 1.0 else value * x
        rows = _zero_rows(1)
        rows[c][0] = value
        return rows

    unit = "N" if c < 3 else "N m"
    per = "·".join(TERM_SIGNALS[f][0] for f in factors)
    return Effect(name, f"generic term {product} on {channel}", (f"coef [{unit}{' / (' + per + ')' if per else ''}]",),
                  columns, ("p", "v") if c < 3 else ("R", "w"))


def entry(name: str) -> Effect:
    """The library entry (or :data:`NOMINAL`, or a generic term) called ``name``."""
    if name == NOMINAL.name:
        return NOMINAL
    if name.startswith(TERM_PREFIX + ":"):
        return _term(name)
    try:
        return LIBRARY[name]
    except KeyError:
        raise KeyError(f"no effect {name!r} in the library; known: {', '.join(LIBRARY)}") from None


def signals(x: Tensor, om: Tensor, om_dot: Tensor, s_slow: Tensor | None = None, vbat: Tensor | None = None,
            lag_in_k_f: Sequence[float] = ()) -> Signals:
    """The components of batched state ``(..., 13)``, rotor speeds and rates ``(..., 4)``, the
    squares' history ``(..., 4 * len(SLOW_TIMES))`` (:func:`slow_squares`) and the battery
    voltage ``(...,)`` where given; ``lag_in_k_f``: see :class:`Signals`."""
    v_b = so3.quat_rotate(so3.quat_conj(x[..., 6:10]), x[..., 3:6])
    return Signals(v=v_b.unbind(-1), w=x[..., 10:13].unbind(-1), om=om.unbind(-1), s=(om * om).unbind(-1),
                   om_dot=om_dot.unbind(-1), z=x[..., 2], s_slow=() if s_slow is None else s_slow.unbind(-1),
                   vbat=vbat, lag_in_k_f=tuple(lag_in_k_f))


def slow_squares(om: Tensor, dt: float, start: Tensor | None = None) -> Tensor:
    """Each rotor's ``Omega_i^2`` through a first-order low-pass of each of :data:`SLOW_TIMES`,
    causal along the time axis of ``om (B, T, 4)`` (rad/s): ``(B, T, 4 * len(SLOW_TIMES))``,
    time constant major. The filter starts at ``start (B, 4 * len)`` (None: at rest at the first
    sample, as a flight starts from a hover); each step is the exact response to a square held
    over ``dt`` s."""
    s = om * om
    a = [1.0 - math.exp(-dt / t) for t in SLOW_TIMES]
    state = s[:, 0].repeat(1, len(SLOW_TIMES)) if start is None else start
    if s.shape[1] > 256 and not s.requires_grad:
        # a whole flight: the same recursion as scipy's filter (y_n = (1 - a) y_(n-1) + a x_n)
        from scipy.signal import lfilter

        x = s.repeat(1, 1, len(SLOW_TIMES)).cpu().numpy()
        cols = [lfilter([ak], [1.0, ak - 1.0], x[:, :, 4 * k:4 * k + 4], axis=1,
                        zi=((1.0 - ak) * state[:, 4 * k:4 * k + 4].cpu().numpy())[:, None, :])[0]
                for k, ak in enumerate(a)]
        return torch.from_numpy(np.concatenate(cols, axis=-1)).to(om)
    gain = torch.tensor([x for x in a for _ in range(4)], dtype=om.dtype, device=om.device)
    out = []
    for k in range(s.shape[1]):
        state = state + gain * (s[:, k].repeat(1, len(SLOW_TIMES)) - state)
        out.append(state)
    return torch.stack(out, dim=1)


def features(names: Sequence[str], x: Tensor, om: Tensor, om_dot: Tensor, vehicle: Vehicle, *,
             s_slow: Tensor | None = None, vbat: Tensor | None = None, lag_in_k_f: Sequence[float] = ()) -> Tensor:
    """The columns of the named effects side by side, ``(..., 6, sum P)``: the regression's
    features, and with coefficients ``theta`` the augmented model's wrench ``features @ theta``.
    ``s_slow``, ``vbat`` and ``lag_in_k_f``: see :func:`signals` (the entries that need the first
    two are zero without)."""
    sg = signals(x, om, om_dot, s_slow, vbat, lag_in_k_f)
    # most entries are the constant 0: the output starts as zeros, and the signal columns and the
    # other constants go in with one copy each (the regression's and every rollout step's cost)
    cols: list[Tensor] = []
    at: list[tuple[int, int]] = []
    consts: list[float] = []
    const_at: list[tuple[int, int]] = []
    P = 0
    for name in names:
        rows = entry(name).columns(sg, vehicle)
        for c, row in enumerate(rows):
            for k, e in enumerate(row):
                if isinstance(e, Tensor):
                    cols.append(e)
                    at.append((c, P + k))
                elif e != 0.0:
                    consts.append(float(e))
                    const_at.append((c, P + k))
        P += len(rows[0])
    out = torch.zeros((*x.shape[:-1], 6 * P), dtype=x.dtype, device=x.device)
    if cols:
        out.index_copy_(out.dim() - 1, torch.tensor([c * P + j for c, j in at], device=x.device),
                        torch.stack(cols, dim=-1).to(x.dtype))
    if consts:
        out[..., torch.tensor([c * P + j for c, j in const_at], device=x.device)] = torch.tensor(
            consts, dtype=x.dtype, device=x.device)
    return out.view(*x.shape[:-1], 6, P)


def wrench(name: str, theta: Sequence[float], sg: Signals, vehicle: Vehicle) -> tuple[list[Any], list[Any]]:
    """Body force and torque (3 entries each) of one effect with coefficients ``theta``,
    over component scalars: what the generated C computes."""
    out = []
    for row in entry(name).columns(sg, vehicle):
        total: Any = 0.0
        for col, th in zip(row, theta):
            if isinstance(col, float) and col == 0.0:
                continue
            total = col * float(th) if isinstance(total, float) and total == 0.0 else total + col * float(th)
        out.append(total)
    return out[:3], out[3:]


def refitted_vehicle(vehicle: Vehicle, dk_f: float, dk_m: float, corrections: dict[str, Sequence[float]]) -> Vehicle:
    """The vehicle with the refitted k_F (thrust) and k_M and the corrections applied; the arm is
    scaled so that the roll/pitch torques' k_F L is what the ``arm`` correction (if any) says."""
    v = apply_corrections(vehicle, corrections)
    k_f = vehicle.k_f + dk_f
    return dataclasses.replace(v, k_f=k_f, k_m=vehicle.k_m + dk_m, arm=v.arm * vehicle.k_f / k_f)


def apply_corrections(vehicle: Vehicle, corrections: dict[str, Sequence[float]]) -> Vehicle:
    """The vehicle with the named parameter corrections (``inertia``, ``arm``) added."""
    kw: dict[str, Any] = {}
    for name, theta in corrections.items():
        if name == "inertia":
            kw["inertia"] = tuple(j + float(d) for j, d in zip(vehicle.inertia, theta))
        elif name == "arm":
            kw["arm"] = vehicle.arm + float(theta[0])
        else:
            raise KeyError(f"{name!r} is not a parameter correction")
    return dataclasses.replace(vehicle, **kw)


def split_coefficients(names: Sequence[str], theta: Sequence[float]) -> dict[str, list[float]]:
    """A coefficient vector laid out as :func:`features` lays out its columns, per effect."""
    out, k = {}, 0
    for name in names:
        n = entry(name).n_columns
        out[name] = [float(t) for t in theta[k:k + n]]
        k += n
    if k != len(theta):
        raise ValueError(f"{len(theta)} coefficients for effects {list(names)}, which take {k}")
    return out
