"""Measured against predicted body wrench, and the regression that names effects.

The measured wrench is what the rigid body must have felt: force ``m a_IMU`` from the
accelerometer, torque ``J dω/dt + ω × Jω`` from the gyro (Savitzky-Golay derivative, as the
identify stage). The nominal model predicts ``[0, 0, k_F ΣΩ²]`` and the paper's mixer torques.
Their difference, per channel, is what the candidates must explain. Model-side signals are
smoothed with the same Savitzky-Golay window, so the filter does not show up as a disagreement.

Every fit is a weighted least-squares problem over the six channels (each weighted by the
inverse spread of its nominal residual on the training flights), and every score is held out:
leave one training flight out, fit on the others, measure on it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
from scipy.signal import savgol_filter

from nanosysid import effects
from nanosysid.dataio import Flight
from nanosysid.identify import body_torque
from nanosysid.rollout import advance_inputs
from nanosysid.vehicle import Vehicle

__all__ = ["FlightData", "flight_data", "nominal_wrench", "measured_wrench", "Fitter"]

EDGE = 10  # samples dropped at each end of a flight: the smoothing filter's edge effects


def measured_wrench(flight: Flight, vehicle: Vehicle, window: int, order: int) -> np.ndarray:
    """``[m a_IMU; J dω/dt + ω × Jω]`` in the body frame, ``(T, 6)``."""
    acc = np.column_stack([flight.extra[c] for c in ("ax_body", "ay_body", "az_body")])
    force = vehicle.mass * savgol_filter(acc, window, order, axis=0)
    return np.column_stack([force, body_torque(flight, vehicle.inertia, window=window, polyorder=order)])


def nominal_wrench(u: np.ndarray, vehicle: Vehicle) -> np.ndarray:
    """The quadratic rotor model's ``[0, 0, T; tau]``, ``(T, 6)``."""
    from nanosysid.dynamics import rotor_wrench

    thrust, tau = rotor_wrench(torch.from_numpy(u), k_f=vehicle.k_f, k_m=vehicle.k_m, arm=vehicle.arm)
    w = np.zeros((len(u), 6))
    w[:, 2] = thrust.numpy()
    w[:, 3:] = tau.numpy()
    return w


@dataclass
class FlightData:
    """One flight's regression data for one rotor-speed delay: the residual wrench ``r (T, 6)``
    and each library effect's features ``(T, 6, P)``, smoothed and trimmed at the edges."""

    name: str
    r: np.ndarray
    features: dict[str, np.ndarray] = field(default_factory=dict)


def _smooth(a: np.ndarray, window: int, order: int) -> np.ndarray:
    return savgol_filter(a, window, order, axis=0)


def flight_data(flight: Flight, vehicle: Vehicle, delay: float, *, window: int = 15, order: int = 3,
                measured: np.ndarray | None = None) -> FlightData:
    """The residual and the candidates' features of a flight, rotor speeds advanced by ``delay``."""
    dt = float(np.median(np.diff(flight.t)))
    u = advance_inputs(torch.from_numpy(flight.u)[None], delay / dt)[0].numpy()  # read delay later
    om_dot = savgol_filter(u, window, order, deriv=1, delta=dt, axis=0)
    meas = measured_wrench(flight, vehicle, window, order) if measured is None else measured
    r = meas - _smooth(nominal_wrench(u, vehicle), window, order)
    x, om, od = (torch.from_numpy(np.ascontiguousarray(a)) for a in (flight.y, u, om_dot))
    feats = {}
    for e in (effects.NOMINAL, *(e for e in effects.LIBRARY.values() if e.columns is not None)):
        feats[e.name] = _smooth(effects.features([e.name], x, om, od, vehicle).numpy(), window, order)[EDGE:-EDGE]
    return FlightData(flight.name, r[EDGE:-EDGE], feats)


class Fitter:
    """Weighted least squares of the residual on candidate features, over flights.

    Args:
        data: One :class:`FlightData` per training flight (all for the same delay).
        weights: Per-channel weights ``(6,)``: the inverse spread of the nominal residual.
    """

    def __init__(self, data: list[FlightData], weights: np.ndarray) -> None:
        self.data, self.w = data, weights

    def _system(self, names: list[str], idx) -> tuple[np.ndarray, np.ndarray]:
        X = np.concatenate([np.concatenate([self.data[i].features[n] for n in names], axis=-1) * self.w[:, None]
                            for i in idx])  # (N, 6, P)
        y = np.concatenate([self.data[i].r * self.w for i in idx])  # (N, 6)
        return X.reshape(-1, X.shape[-1]), y.reshape(-1)

    def fit(self, names: list[str], idx=None) -> np.ndarray:
        """Coefficients of the named candidates (in order, each with its P columns)."""
        idx = range(len(self.data)) if idx is None else idx
        A, b = self._system(names, idx)
        scale = np.linalg.norm(A, axis=0)
        scale[scale == 0] = 1.0
        sol, *_ = np.linalg.lstsq(A / scale, b, rcond=None)
        return sol / scale

    def sse(self, names: list[str], theta: np.ndarray, idx) -> float:
        """Weighted sum of squared residuals left on flights ``idx``."""
        A, b = self._system(names, idx)
        return float(((b - A @ theta) ** 2).sum())

    def cv(self, names: list[str]) -> tuple[np.ndarray, np.ndarray]:
        """Held-out SSE of each flight (fitted on the others) and the coefficients of each fold."""
        n = len(self.data)
        sse, thetas = np.zeros(n), []
        for i in range(n):
            rest = [j for j in range(n) if j != i]
            th = self.fit(names, rest)
            sse[i] = self.sse(names, th, [i])
            thetas.append(th)
        return sse, np.array(thetas)

    def nominal_sse(self, idx=None) -> float:
        """SSE of the residual itself (nothing explained)."""
        idx = range(len(self.data)) if idx is None else idx
        return float(sum(((self.data[i].r * self.w) ** 2).sum() for i in idx))
