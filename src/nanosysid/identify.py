"""Least-squares identification of the rotor coefficients k_F and k_M (paper, Parameter Estimation).

- Thrust: the accelerometer measures the specific force, so ``m a_z^IMU = k_F sum_i Omega_i^2``
  (least squares through the origin, as in the paper).
- Yaw moment: the torque reconstructed from the gyro, ``tau = J dw/dt + w x (J w)``, with the
  derivative from a Savitzky-Golay filter (a local polynomial fit does not amplify the noise
  the way a finite difference does), against ``k_M (-O1^2 + O2^2 - O3^2 + O4^2)``. The fit has
  an intercept: a constant yaw torque the rotor model does not know (unequal rotors, say)
  is trimmed by the controller with a constant rotor-speed difference, which a fit through the
  origin would read as part of k_M.

Both use the training flights only, and both are the paper's method: least squares on
closed-loop flights. In closed loop the controller answers every disturbance through the
rotor speeds the fit regresses on (the yaw loop sets the rotor-speed difference to cancel a yaw
disturbance torque), so the regressor and the residual are correlated and k_M in particular
can be biased well beyond its interval; ``params.json`` says so. The standard errors and 95 %
intervals come from the flights as independent repeats (a delete-one-flight jackknife with
Student's t), not from the white-residual formula, which the residuals' correlation in time
makes far too narrow; the white-residual error is kept beside it.

The yaw torque is read from the gyro with the vehicle's yaw inertia J_z, which the flights do not
identify (every yaw coefficient scales with it): k_M's interval is also given with J_z anywhere in
the range the sources give for the airframe (:func:`with_inertia_range`).

The result, ``params.json``, is written and read through
one pair of functions (:func:`write_identified`, :func:`read_identified`); the physics models,
discovery and the export take k_F and k_M from it (:func:`identified_vehicle`).
"""

from __future__ import annotations

import dataclasses
import math
import logging
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from nanosysid.dataio import atomic_file, Flight, flight_list, json_text, read_json_record
from nanosysid.dynamics import SPIN
from nanosysid.errors import ConfigError, DataError
from nanosysid.vehicle import Vehicle

_log = logging.getLogger(__name__)

__all__ = ["Fit", "fit_thrust", "fit_yaw_moment", "fit_yaw_moment_iv", "identify", "body_torque", "yaw_regressor",
           "with_inertia_range", "write_identified", "read_identified", "identified_vehicle"]

FORMAT = "nanosysid-identified-1"
CLOSED_LOOP_BIAS = ("possible: no calibration flight with yaw excitation, so k_M is least squares on closed-loop "
                    "flights; the controller's answers to yaw disturbances correlate the rotor speeds with the "
                    "residual, which biases k_M (towards zero) beyond its interval")


@dataclass(frozen=True)
class Fit:
    """A linear least-squares fit ``y = coef x (+ intercept)``.

    ``stderr`` is the white-residual formula's; ``jackknife_se`` and ``ci95`` come from the
    flights as repeats (None with fewer than two flights); ``condition`` is the condition
    number of the regression matrix with unit-norm columns. A yaw fit's ``ci95`` holds for the
    vehicle's yaw inertia J_z; ``ci95_inertia`` widens it to every J_z in ``inertia_z_range``
    (:func:`with_inertia_range`).
    """

    coef: float
    stderr: float
    r2: float
    intercept: float
    n: int
    jackknife_se: float | None = None
    ci95: tuple[float, float] | None = None
    flights: int = 1
    condition: float = 1.0
    estimator: str = "least squares on closed-loop flights (the paper's method)"
    terms: dict[str, float] = field(default_factory=dict)
    ci95_inertia: tuple[float, float] | None = None
    inertia_z_range: tuple[float, float] | None = None

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        for key in ("ci95", "ci95_inertia", "inertia_z_range"):
            d[key] = None if d[key] is None else list(d[key])
        return d


def _design(x: np.ndarray, intercept: bool) -> np.ndarray:
    return np.column_stack((x, np.ones_like(x))) if intercept else x[:, None]


def _lstsq(xs: Sequence[np.ndarray], ys: Sequence[np.ndarray], intercept: bool) -> Fit:
    """The fit on the flights' samples pooled (one array per flight in ``xs``, ``ys``), with a
    delete-one-flight jackknife of its coefficient."""
    x, y = np.concatenate(xs), np.concatenate(ys)
    A = _design(x, intercept)
    sol, *_ = np.linalg.lstsq(A, y, rcond=None)
    resid = y - A @ sol
    dof = len(y) - A.shape[1]
    cov = np.linalg.inv(A.T @ A) * (resid @ resid) / dof
    ss_tot = ((y - y.mean()) ** 2).sum() if intercept else (y**2).sum()
    k = len(xs)
    se = ci = None
    if k > 1:
        loo = np.array([np.linalg.lstsq(_design(np.concatenate(xs[:i] + xs[i + 1:]), intercept),
                                        np.concatenate(ys[:i] + ys[i + 1:]), rcond=None)[0][0]
                        for i in range(k)])
        se = float(np.sqrt((k - 1) / k * ((loo - loo.mean()) ** 2).sum()))
        half = _t975(k - 1) * se
        ci = (float(sol[0]) - half, float(sol[0]) + half)
    return Fit(
        coef=float(sol[0]),
        stderr=float(np.sqrt(cov[0, 0])),
        r2=float(1 - (resid @ resid) / ss_tot),
        intercept=float(sol[1]) if intercept else 0.0,
        n=len(y),
        jackknife_se=se,
        ci95=ci,
        flights=k,
        condition=float(np.linalg.cond(A / np.linalg.norm(A, axis=0))),
    )


def fit_thrust(flights: Sequence[Flight], vehicle: Vehicle) -> Fit:
    """k_F (N s^2/rad^2) from ``m a_z = k_F sum Omega^2``."""
    return _lstsq([(f.u**2).sum(axis=1) for f in flights], [vehicle.mass * f.extra["az_body"] for f in flights],
                  intercept=False)


def body_torque(flight: Flight, inertia: Sequence[float], *, window: int = 15, polyorder: int = 3) -> np.ndarray:
    """Torque (N m, body frame) ``J dw/dt + w x (J w)`` from the gyro, shape ``(T, 3)``."""
    dt = float(np.median(np.diff(flight.t)))
    w = flight.y[:, 10:13]
    w_dot = _derivative(w, dt, window, polyorder)
    J = np.asarray(inertia)
    return J * w_dot + np.cross(w, J * w)


def yaw_regressor(u: np.ndarray) -> np.ndarray:
    """``-O1^2 + O2^2 - O3^2 + O4^2``, the yaw row of the paper's mixing matrix over k_M."""
    return (u**2) @ np.array([-1.0, 1.0, -1.0, 1.0])


def fit_yaw_moment(flights: Sequence[Flight], vehicle: Vehicle, *, window: int = 15, polyorder: int = 3) -> Fit:
    """k_M (N m s^2/rad^2) from the reconstructed yaw torque, with an intercept."""
    return _lstsq([yaw_regressor(f.u) for f in flights],
                  [body_torque(f, vehicle.inertia, window=window, polyorder=polyorder)[:, 2] for f in flights],
                  intercept=True)


def _t975(dof: int) -> float:
    """Student's t quantile of a two-sided 95 % interval with ``dof`` degrees of freedom."""
    from scipy.stats import t as student_t  # here: scipy.stats costs 0.7 s, and every predictor imports this module

    return float(student_t.ppf(0.975, dof))


def _derivative(x: np.ndarray, dt: float, window: int, polyorder: int, deriv: int = 1) -> np.ndarray:
    from scipy.signal import savgol_filter

    return savgol_filter(x, window, polyorder, deriv=deriv, delta=dt, axis=0)


def _yaw_iv_columns(f: Flight, vehicle: Vehicle, *, window: int, polyorder: int,
                    lags: Sequence[float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One calibration flight's yaw torque ``y (T,)``, regressors ``X (T, 4)`` and instruments
    ``Z (T, K)``, cut to the samples where every lagged instrument exists."""
    dt = float(np.median(np.diff(f.t)))
    spin = np.array(SPIN)
    y = body_torque(f, vehicle.inertia, window=window, polyorder=polyorder)[:, 2]
    omega_dot = _derivative(f.u, dt, window, polyorder)
    X = np.column_stack((yaw_regressor(f.u), omega_dot @ spin, f.y[:, 12], np.ones(len(f))))
    ref = f.extra["yaw_ref"]
    derivs = [ref] + [_derivative(ref, dt, window, polyorder, d) for d in (1, 2, 3)]
    shift = [int(round(lag / dt)) for lag in lags]
    k0 = max(shift)
    Z = np.column_stack([d[k0 - s:len(f) - s] for d in derivs for s in shift] + [np.ones(len(f) - k0)])
    return y[k0:], X[k0:], Z


def _two_stage(y: np.ndarray, X: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """Two-stage least squares: ``X`` projected on the instruments ``Z``, then ``y`` on that."""
    X_hat = Z @ np.linalg.lstsq(Z, X, rcond=None)[0]
    return np.linalg.solve(X_hat.T @ X, X_hat.T @ y)


def fit_yaw_moment_iv(flights: Sequence[Flight], vehicle: Vehicle, *, window: int = 15, polyorder: int = 3,
                      lags: Sequence[float] = (0.0, 0.1, 0.2, 0.3), blocks: int = 10) -> Fit:
    """k_M by instrumental variables on calibration flights with yaw excitation.

    The yaw torque reconstructed from the gyro is regressed on ``k_M (-O1^2 + O2^2 - O3^2 +
    O4^2)``, the rotors' reaction to their own acceleration (``sum s_i dOmega_i/dt``, whose
    coefficient is minus the rotor inertia), a yaw-damping term ``w_z`` and a constant. In
    closed loop these regressors carry the controller's answers to the yaw disturbances; the
    instruments do not: the yaw setpoint ``yaw_ref`` and its first three derivatives at the
    given ``lags`` (s), exogenous by design. The interval is a delete-one-block jackknife over
    ``blocks`` contiguous blocks of each flight (Student's t).

    Raises:
        DataError: a flight without a yaw setpoint (``yaw_ref`` column).
    """
    for f in flights:
        if "yaw_ref" not in f.extra:
            raise DataError(f"identify: calibration flight {f.name} has no yaw_ref column (the yaw setpoint)")
    parts = [_yaw_iv_columns(f, vehicle, window=window, polyorder=polyorder, lags=lags) for f in flights]
    y, X, Z = (np.concatenate([p[i] for p in parts]) for i in range(3))
    beta = _two_stage(y, X, Z)
    resid = y - X @ beta
    # blocks of every flight, for the jackknife
    label = np.concatenate([np.minimum(np.arange(len(p[0])) * blocks // len(p[0]), blocks - 1) + blocks * i
                            for i, p in enumerate(parts)])
    units = np.unique(label)
    loo = np.array([_two_stage(y[label != b], X[label != b], Z[label != b])[0] for b in units])
    n = len(units)
    se = float(np.sqrt((n - 1) / n * ((loo - loo.mean()) ** 2).sum()))
    half = _t975(n - 1) * se
    A = X / np.linalg.norm(X, axis=0)
    return Fit(
        coef=float(beta[0]),
        stderr=float("nan"),
        r2=float(1 - (resid @ resid) / ((y - y.mean()) ** 2).sum()),
        intercept=float(beta[3]),
        n=len(y),
        jackknife_se=se,
        ci95=(float(beta[0]) - half, float(beta[0]) + half),
        flights=len(flights),
        condition=float(np.linalg.cond(A)),
        estimator=f"instrumental variables on {len(flights)} yaw calibration flight(s): the yaw setpoint and its "
                  "derivatives as instruments; rotor-inertia and yaw-damping terms in the regression; interval by "
                  f"jackknife over {n} blocks",
        terms={"rotor_inertia": float(-beta[1]), "yaw_damping": float(beta[2])},
    )


def with_inertia_range(fit: Fit, inertia_z: float, inertia_z_range: Sequence[float] | None) -> Fit:
    """A yaw fit whose interval also spans the yaw inertia's uncertainty.

    The yaw torque is read from the gyro as ``J_z dw_z/dt + (J_y - J_x) w_x w_y``, so every
    coefficient of a yaw fit (k_M, the rotor inertia, the damping) scales with the J_z it was
    read with (``inertia_z``, kg m^2; exactly where J_x = J_y): the flights identify k_M / J_z,
    not k_M. ``ci95_inertia`` is ``ci95`` with J_z anywhere in ``inertia_z_range`` (kg m^2, the
    range the sources give for the airframe): ``(low * J_lo / J_z, high * J_hi / J_z)``. The
    estimate stays the one for the vehicle's J_z. None: the fit unchanged.

    Raises:
        DataError: a range that is not two positive numbers, low to high, holding ``inertia_z``.
    """
    if inertia_z_range is None or fit.ci95 is None:
        return fit
    bounds = [float(v) for v in inertia_z_range]
    lo, hi = (bounds + [math.nan, math.nan])[:2]
    if len(bounds) != 2 or not (0 < lo <= inertia_z <= hi):
        raise DataError(f"identify.inertia_z_range: {bounds} kg m^2 does not hold the vehicle's yaw "
                        f"inertia {inertia_z:.4g} (vehicle.inertia[2]); give the range the sources allow, low to high")
    return dataclasses.replace(fit, ci95_inertia=(fit.ci95[0] * lo / inertia_z, fit.ci95[1] * hi / inertia_z),
                               inertia_z_range=(lo, hi))


def identify(flights: Sequence[Flight], vehicle: Vehicle, *, window: int = 15, polyorder: int = 3) -> tuple[Fit, Fit]:
    """The thrust fit (k_F) and the yaw-moment fit (k_M) on ``flights``, both by the paper's
    method (least squares); a thrust fit the vehicle cannot have is refused (:func:`check_thrust`)."""
    flights = flight_list(flights, "identify")
    if not flights:
        raise DataError("identify: no training flight to fit k_F and k_M on")
    check_inputs(flights, window, polyorder)
    try:
        thrust = fit_thrust(flights, vehicle)
        check_thrust(thrust, vehicle)
        return thrust, fit_yaw_moment(flights, vehicle, window=window, polyorder=polyorder)
    except np.linalg.LinAlgError as e:
        raise DataError(f"identify: the flights do not determine k_F and k_M ({e}): the rotor speeds' squares and "
                        "their yaw combination must vary over the flights") from None


def check_inputs(flights: Sequence[Flight], window: int, polyorder: int) -> None:
    """Refuse what the fits cannot read: a flight without the accelerometer's ``az_body``, or a
    Savitzky-Golay ``window`` (above ``polyorder``, within the shortest flight) and
    ``polyorder`` (a whole number >= 1) the derivatives cannot have.

    Raises:
        DataError: the flight and the column; ConfigError: the setting and its value.
    """
    for f in flights:
        if "az_body" not in f.extra:
            raise DataError(f"identify: flight {f.name} has no column 'az_body' (the accelerometer's specific force, "
                            "m/s², which k_F is fitted to)")
    shortest = min(len(f) for f in flights)
    for name, v in (("window", window), ("polyorder", polyorder)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise ConfigError(f"identify: {name} (identify.savgol_{name if name == 'window' else 'order'}) must be a "
                              f"whole number >= 1, got {v!r}")
    if not polyorder < window <= shortest:
        raise ConfigError(f"identify: window = {window} (identify.savgol_window) with polyorder = {polyorder}: the "
                          f"Savitzky-Golay window must be above the polynomial order and at most the shortest "
                          f"flight's {shortest} samples")


# how far from the vehicle's nominal an identified coefficient may lie: k_F is determined to a
# per cent even in closed loop, and a propeller's is known from thrust stands within about
# 10 %, so 25 % off is a unit or a setting (a motor pole-pair count of 7 for 6 gives +36 %);
# the paper's least squares puts k_M several times low in closed loop, and that estimate is
# still reported, with its warning
PLAUSIBLE_FACTOR = {"k_F": 1.25, "k_M / k_F": 10.0}
MIN_THRUST_R2 = 0.5  # the thrust must explain most of the vertical force, or the data are not flight


def _where(name: str, fit: Fit) -> str:
    ci = "" if fit.ci95 is None else f", 95 % interval {fit.ci95[0]:.4g} to {fit.ci95[1]:.4g}"
    return f"identify: {name} = {fit.coef:.4g}{ci}, R² {fit.r2:.3f} ({fit.flights} flight(s), {fit.estimator})"


def _off(value: float, nominal: float, name: str) -> bool:
    k = PLAUSIBLE_FACTOR[name]
    return not (np.isfinite(value) and nominal / k <= value <= nominal * k)


def check_thrust(thrust: Fit, vehicle: Vehicle) -> None:
    """Refuse a thrust fit the vehicle cannot have: R² below :data:`MIN_THRUST_R2`, or k_F
    further than :data:`PLAUSIBLE_FACTOR` from the nominal ``vehicle``'s (a unit mistake: rpm
    for rad/s, gravity left out of the accelerometer, a wrong motor pole-pair count).

    Raises:
        DataError: naming the estimate, its interval and R², and what to check.
    """
    if not thrust.r2 >= MIN_THRUST_R2:
        raise DataError(f"{_where('k_F', thrust)}: the thrust explains less than {MIN_THRUST_R2:g} of the vertical "
                        "force; check that the accelerometer and the rotor speeds were recorded together, and the "
                        "accelerometer's unit (m/s², with gravity)")
    if _off(thrust.coef, vehicle.k_f, "k_F"):
        raise DataError(f"{_where('k_F', thrust)}: {thrust.coef / vehicle.k_f:.3g} times the vehicle's nominal "
                        f"{vehicle.k_f:.4g}, outside 1/{PLAUSIBLE_FACTOR['k_F']:g} to {PLAUSIBLE_FACTOR['k_F']:g}; check "
                        "the rotor speeds' unit (rad/s: the topic map's motors.pole_pairs and erpm_unit), the "
                        "accelerometer's (m/s², with gravity) and vehicle.mass, or set vehicle.k_f for other propellers")


def check_plausible(thrust: Fit, yaw: Fit, vehicle: Vehicle) -> None:
    """Refuse coefficients the vehicle cannot have, or that the data do not determine, before they
    are written: the thrust fit as :func:`check_thrust` does, the yaw torque per thrust k_M / k_F
    further than :data:`PLAUSIBLE_FACTOR` from the nominal ``vehicle``'s, or a 95 % interval that
    holds zero.

    Raises:
        DataError: naming the coefficient, its estimate, interval and R², and what would help.
    """
    check_thrust(thrust, vehicle)
    arm, nominal_arm = yaw.coef / thrust.coef, vehicle.k_m / vehicle.k_f
    if _off(arm, nominal_arm, "k_M / k_F"):
        raise DataError(f"{_where('k_M', yaw)}: k_M / k_F = {arm * 1e3:.3g} mm, more than "
                        f"{PLAUSIBLE_FACTOR['k_M / k_F']:g} times "
                        f"off the vehicle's nominal {nominal_arm * 1e3:.3g} mm; the flights do not determine the yaw "
                        "torque (fly a yaw calibration flight, or flights with yaw manoeuvres)")
    for name, fit in (("k_F", thrust), ("k_M", yaw)):
        if fit.ci95 is not None and np.all(np.isfinite(fit.ci95)) and fit.ci95[0] <= 0:
            raise DataError(f"{_where(name, fit)}: the interval holds zero, so the flights do not determine it; "
                            "add flights that excite it (a yaw calibration flight for k_M)")


def write_identified(path: str | Path, thrust: Fit, yaw: Fit, flights: Sequence[Flight], *,
                yaw_paper: Fit | None = None, calibration: Sequence[Flight] = ()) -> dict[str, Any]:
    """Write ``params.json``: k_F and k_M, their fits (estimator, 95 % interval, conditioning),
    and the flights they were fitted on. ``yaw_paper`` is the paper's least-squares k_M, kept
    beside ``yaw`` when another estimator gave k_M (from the ``calibration`` flights)."""
    payload = {"format": FORMAT, "k_f": thrust.coef, "k_m": yaw.coef, "thrust_fit": thrust.to_dict(),
               "yaw_fit": yaw.to_dict(), "train_flights": [f.name for f in flights],
               "calibration_flights": [f.name for f in calibration]}
    if yaw_paper is not None:
        payload["yaw_fit_paper_method"] = yaw_paper.to_dict()
    payload["closed_loop_bias"] = CLOSED_LOOP_BIAS if not calibration else (
        "k_M from the calibration flights by instrumental variables, which the controller's answers to "
        "disturbances do not bias; k_F by least squares (the thrust loop is excited by every trajectory's "
        "sharp thrust changes); yaw_fit_paper_method shows the paper's least squares on the same training flights")
    with atomic_file(Path(path)) as tmp:
        tmp.write_text(json_text(payload))
    return payload


def read_identified(path: str | Path) -> dict[str, Any]:
    """Read a ``params.json`` written by :func:`write_identified`, checked: k_F and k_M positive and finite."""
    path = Path(path)
    d = read_json_record(path, FORMAT, "identified parameters", "identify")
    for key in ("k_f", "k_m"):
        v = d.get(key)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
            raise DataError(f"{path}: field {key!r} is {v!r}, expected a positive number")
    return d


def identified_vehicle(vehicle: Vehicle, path: str | Path | None) -> Vehicle:
    """``vehicle`` with k_F and k_M from the identify stage's ``params.json``; ``path`` None
    keeps the vehicle's own (a deliberate choice of the config, ``identified: null``)."""
    if path is None:
        return vehicle
    d = read_identified(path)
    k_f, k_m = float(d["k_f"]), float(d["k_m"])
    # the identify stage writes nothing outside these bounds: a value outside is a file edited by
    # hand or written for another vehicle, which would be scored as if it were this one's
    bounds = (("k_f", k_f, vehicle.k_f, PLAUSIBLE_FACTOR["k_F"], "vehicle.k_f"),
              ("k_m", k_m / k_f, vehicle.k_m / vehicle.k_f, PLAUSIBLE_FACTOR["k_M / k_F"], "vehicle.k_m"))
    for key, value, nominal, factor, setting in bounds:
        if not nominal / factor <= value <= nominal * factor:
            what = "k_f" if key == "k_f" else "k_m / k_f"
            raise DataError(f"{path}: field {key!r} is {d[key]!r}: {what} = {value:.4g}, more than {factor:g} times off "
                            f"the vehicle's {nominal:.4g} ({setting}); the identify stage writes this file (rerun it), "
                            f"or set {setting} for another vehicle")
    # which file a run's k_F and k_M came from is part of its record (an override may move it)
    _log.info("k_F = %.4g, k_M = %.4g from %s", k_f, k_m, path)
    return dataclasses.replace(vehicle, k_f=k_f, k_m=k_m)
