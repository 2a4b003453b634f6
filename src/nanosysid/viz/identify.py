"""Measured against fitted thrust and yaw torque, as the paper's identification figure."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from nanosysid.dataio import Flight, atomic_file  # noqa: E402
from nanosysid.identify import Fit, body_torque, yaw_regressor  # noqa: E402
from nanosysid.vehicle import Vehicle  # noqa: E402

__all__ = ["identify_figure"]


def identify_figure(flight: Flight, vehicle: Vehicle, thrust: Fit, yaw: Fit, path: Path,
                    window: tuple[float, float] = (20.0, 25.0)) -> None:
    """Two panels over ``window`` (s): thrust ``m a_z`` against ``k_F sum Omega^2``, and the
    gyro-reconstructed yaw torque against ``k_M (...) + offset``."""
    t = flight.t - flight.t[0]
    sel = (t >= window[0]) & (t <= window[1])
    if not sel.any():
        sel = slice(None)
    T_meas = vehicle.mass * flight.extra["az_body"]
    T_fit = thrust.coef * (flight.u**2).sum(axis=1)
    tz_meas = body_torque(flight, vehicle.inertia)[:, 2]
    tz_fit = yaw.coef * yaw_regressor(flight.u) + yaw.intercept
    fig, ax = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    ax[0].plot(t[sel], T_meas[sel], lw=1, color="0.3", label="measured  m·a_z (accelerometer)")
    ax[0].plot(t[sel], T_fit[sel], lw=1.2, color="C0", label=f"fitted  k_F·ΣΩ²,  k_F = {thrust.coef:.4g}  (R² {thrust.r2:.3f})")
    ax[0].set_ylabel("thrust [N]")
    ax[1].plot(t[sel], 1e3 * tz_meas[sel], lw=1, color="0.3", label="measured  J·ω̇ + ω×Jω (gyro), z")
    ax[1].plot(t[sel], 1e3 * tz_fit[sel], lw=1.2, color="C1",
               label=f"fitted  k_M·(−Ω₁²+Ω₂²−Ω₃²+Ω₄²) + c,  k_M = {yaw.coef:.4g}  (R² {yaw.r2:.2f})")
    ax[1].set_ylabel("yaw torque [mN·m]")
    ax[1].set_xlabel(f"time [s], {flight.name}")
    for a in ax:
        a.legend(loc="upper right", fontsize=8)
        a.grid(alpha=0.3)
    fig.suptitle("Identified rotor coefficients on a test flight (fitted on the training flights)")
    fig.tight_layout()
    with atomic_file(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110, metadata={"Software": None})
    plt.close(fig)
