"""Least-squares identification of the rotor coefficients k_F and k_M (paper, Parameter Estimation).

- Thrust: the accelerometer measures the specific force, so ``m a_z^IMU = k_F sum_i Omega_i^2``
  (least squares through the origin, as in the paper).
- Yaw moment: the torque reconstructed from the gyro, ``tau = J dw/dt + w x (J w)``, with the
  derivative from a Savitzky-Golay filter (a local polynomial fit does not amplify the noise
  the way a finite difference does), against ``k_M (-O1^2 + O2^2 - O3^2 + O4^2)``. The fit has
  an intercept: a constant yaw torque the rotor model does not know (unequal rotors, say)
  is trimmed by the controller with a constant rotor-speed difference, which a fit through the
  origin would read as part of k_M.

Both use the training flights only. The result, ``params.json``, is written and read through
one pair of functions (:func:`save_params`, :func:`load_params`); the physics models,
discovery and the export take k_F and k_M from it (:func:`identified_vehicle`).
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from scipy.signal import savgol_filter

from nanosysid.dataio import Flight, atomic_file, read_json_record
from nanosysid.errors import DataError
from nanosysid.vehicle import Vehicle

__all__ = ["Fit", "fit_thrust", "fit_yaw_moment", "identify", "body_torque", "yaw_regressor", "save_params",
           "load_params", "identified_vehicle"]

FORMAT = "nanosysid-identified-1"


@dataclass(frozen=True)
class Fit:
    """A linear least-squares fit ``y = coef x (+ intercept)``."""

    coef: float
    stderr: float
    r2: float
    intercept: float
    n: int

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


def _lstsq(x: np.ndarray, y: np.ndarray, intercept: bool) -> Fit:
    A = np.column_stack((x, np.ones_like(x))) if intercept else x[:, None]
    sol, *_ = np.linalg.lstsq(A, y, rcond=None)
    resid = y - A @ sol
    dof = len(y) - A.shape[1]
    cov = np.linalg.inv(A.T @ A) * (resid @ resid) / dof
    ss_tot = ((y - y.mean()) ** 2).sum() if intercept else (y**2).sum()
    return Fit(
        coef=float(sol[0]),
        stderr=float(np.sqrt(cov[0, 0])),
        r2=float(1 - (resid @ resid) / ss_tot),
        intercept=float(sol[1]) if intercept else 0.0,
        n=len(y),
    )


def fit_thrust(flights: Sequence[Flight], vehicle: Vehicle) -> Fit:
    """k_F (N s^2/rad^2) from ``m a_z = k_F sum Omega^2``."""
    x = np.concatenate([(f.u**2).sum(axis=1) for f in flights])
    y = np.concatenate([vehicle.mass * f.extra["az_body"] for f in flights])
    return _lstsq(x, y, intercept=False)


def body_torque(flight: Flight, inertia: Sequence[float], *, window: int = 15, polyorder: int = 3) -> np.ndarray:
    """Torque (N m, body frame) ``J dw/dt + w x (J w)`` from the gyro, shape ``(T, 3)``."""
    dt = float(np.median(np.diff(flight.t)))
    w = flight.y[:, 10:13]
    w_dot = savgol_filter(w, window, polyorder, deriv=1, delta=dt, axis=0)
    J = np.asarray(inertia)
    return J * w_dot + np.cross(w, J * w)


def yaw_regressor(u: np.ndarray) -> np.ndarray:
    """``-O1^2 + O2^2 - O3^2 + O4^2``, the yaw row of the paper's mixing matrix over k_M."""
    return (u**2) @ np.array([-1.0, 1.0, -1.0, 1.0])


def fit_yaw_moment(flights: Sequence[Flight], vehicle: Vehicle, *, window: int = 15, polyorder: int = 3) -> Fit:
    """k_M (N m s^2/rad^2) from the reconstructed yaw torque, with an intercept."""
    x = np.concatenate([yaw_regressor(f.u) for f in flights])
    y = np.concatenate([body_torque(f, vehicle.inertia, window=window, polyorder=polyorder)[:, 2] for f in flights])
    return _lstsq(x, y, intercept=True)


def identify(flights: Sequence[Flight], vehicle: Vehicle, *, window: int = 15, polyorder: int = 3) -> tuple[Fit, Fit]:
    """The thrust fit (k_F) and the yaw-moment fit (k_M) on ``flights``."""
    if not flights:
        raise DataError("identify: no training flight to fit k_F and k_M on")
    return fit_thrust(flights, vehicle), fit_yaw_moment(flights, vehicle, window=window, polyorder=polyorder)


def save_params(path: str | Path, thrust: Fit, yaw: Fit, flights: Sequence[Flight]) -> dict[str, Any]:
    """Write ``params.json``: k_F and k_M, their fits, and the flights they were fitted on."""
    payload = {"format": FORMAT, "k_f": thrust.coef, "k_m": yaw.coef, "thrust_fit": thrust.to_dict(),
               "yaw_fit": yaw.to_dict(), "train_flights": [f.name for f in flights]}
    with atomic_file(Path(path)) as tmp:
        tmp.write_text(json.dumps(payload, indent=1) + "\n")
    return payload


def load_params(path: str | Path) -> dict[str, Any]:
    """Read a ``params.json`` written by :func:`save_params`, checked: k_F and k_M positive and finite."""
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
    d = load_params(path)
    return dataclasses.replace(vehicle, k_f=float(d["k_f"]), k_m=float(d["k_m"]))
