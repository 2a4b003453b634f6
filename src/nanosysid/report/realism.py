"""The simulated world against the real flights, figure by figure: per trajectory the motion's
statistics (speed, acceleration, tilt, body rates), the measurement noise of each signal, and the
nominal model's force and torque residual (its size and its band); over all flights, how far each
flight's mean residual moves from flight to flight, and the motor lag of each session. Every
figure more than :data:`TOLERANCE` off the real flights' is listed, with what is known of why."""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from nanosysid import dynamics
from nanosysid.dataio import Flight
from nanosysid.discover.fit import EDGE, measured_wrench, nominal_wrench
from nanosysid.discover.stats import half_width, spread
from nanosysid.effects import CHANNELS
from nanosysid.report.stats import flight_stats
from nanosysid.vehicle import Vehicle

__all__ = ["TOLERANCE", "world_figures", "noise_law", "yaw_reaction", "climb_drag", "drag_moment", "torque_bands",
           "analyses", "compare", "markdown"]

TOLERANCE = 0.25


def _white(a: np.ndarray) -> np.ndarray:
    """Std of the white noise on each column (the median absolute second difference, which a
    slow signal barely moves: ``Var(x'') = 6 sigma²`` for white noise)."""
    return np.median(np.abs(np.diff(a, n=2, axis=0)), axis=0) / 0.6745 / np.sqrt(6.0)


def _median_frequency(x: np.ndarray, dt: float) -> float:
    """The frequency (Hz) below which half of the power of ``x`` lies, each bin's power spread
    evenly over its width: the rig's residuals sit at 0.3 Hz, where Welch's bins are 0.1 Hz wide
    and the nearest bin would move the figure by a third. The flight's mean is taken out once,
    not each segment's: a segment's own mean is power below its 0.1 Hz."""
    from scipy.signal import welch

    f, p = welch(x - x.mean(), fs=1 / dt, nperseg=min(1024, len(x)), detrend=False)
    df = f[1] - f[0]
    edges = np.concatenate([[0.0], np.minimum(f + df / 2, f[-1])])
    c = np.concatenate([[0.0], np.cumsum(p)])
    return float(np.interp(0.5 * c[-1], c, edges))


# the sensors whose white noise the comparison reads, with their units
SENSORS = (("gyro", "rad/s"), ("accelerometer", "m/s²"), ("rotor speed", "rad/s"))


def _noise(f: Flight) -> list[float]:
    """Each of :data:`SENSORS`' white noise over a flight: the median over its axes of
    :func:`_white`."""
    acc = np.column_stack([f.extra[c] for c in ("ax_body", "ay_body", "az_body")])
    return [float(np.median(_white(v))) for v in (f.y[:, 10:13], acc, f.u)]


def _residual(f: Flight, vehicle: Vehicle, window: int, order: int) -> np.ndarray:
    """The nominal model's force (N) and torque (N m) residual ``(T', 6)``, the edges of the
    derivative's window left out."""
    return (measured_wrench(f, vehicle, window, order) - nominal_wrench(f.u, vehicle))[EDGE:-EDGE]


def _residuals(flights: Sequence[Flight], vehicle: Vehicle, window: int, order: int) -> list[np.ndarray]:
    return [_residual(f, vehicle, window, order) for f in flights]


def _flight(f: Flight, r: np.ndarray, gravity: float) -> dict[str, float]:
    s = flight_stats(f, gravity)
    out = {"v_mean [m/s]": s["v_mean"], "v_max [m/s]": s["v_max"], "a_max [m/s²]": s["a_max"],
           "tilt_max [°]": s["tilt_max"]}
    for i, ax in enumerate("xyz"):
        out[f"rate_{ax} RMS [rad/s]"] = float(np.sqrt(np.mean(f.y[:, 10 + i] ** 2)))
    for (name, unit), level in zip(SENSORS, _noise(f)):
        out[f"{name} noise [{unit}]"] = level
    dt = float(np.median(np.diff(f.t)))
    for c, ch in enumerate(CHANNELS):
        unit = "mN" if c < 3 else "mN·m"
        out[f"{ch} residual [{unit} RMS]"] = float(1e3 * np.sqrt(np.mean((r[:, c] - r[:, c].mean()) ** 2)))
        out[f"{ch} residual median frequency [Hz]"] = _median_frequency(r[:, c], dt)
    return out


def world_figures(flights: Sequence[Flight], vehicle: Vehicle, window: int = 15, order: int = 3
                  ) -> dict[str, dict[str, float]]:
    """Per trajectory, each figure averaged over its runs (the nominal model's residual with
    ``vehicle``, the k_F and k_M its pipeline identified); under ``all``, the standard deviation
    over the flights of each flight's mean residual: a constant of a flight (where the vehicle
    changes between flights) that a model starting from the state alone cannot know."""
    return _world_figures(flights, _residuals(flights, vehicle, window, order), vehicle.gravity)


def _world_figures(flights: Sequence[Flight], residuals: Sequence[np.ndarray], gravity: float
                   ) -> dict[str, dict[str, float]]:
    by: dict[str, list[dict[str, float]]] = {}
    means = []
    for f, r in zip(flights, residuals):
        means.append(r.mean(axis=0))
        by.setdefault(f.trajectory, []).append(_flight(f, r, gravity))
    out = {t: {k: float(np.mean([r[k] for r in runs])) for k in runs[0]} for t, runs in by.items()}
    if len(means) > 1:
        s = 1e3 * spread(np.asarray(means))[0]
        out["all"] = {f"{ch} residual, spread of the flights' means [{'mN' if c < 3 else 'mN·m'}]": float(s[c])
                      for c, ch in enumerate(CHANNELS)}
    return out


def noise_law(flights: Sequence[Flight]) -> dict[str, float]:
    """How each sensor's noise grows with the rotors' motion over ``flights``: ``noise² = n0² (1 +
    (a / ref)²)`` fitted by least squares over the flights, ``noise`` a flight's white noise
    (gyro, accelerometer, rotor speeds, as :func:`world_figures` reads it) and ``a`` its rotors'
    mean ``|dOmega/dt|`` (rad/s², the speeds smoothed over 5 samples); ``ref`` (rad/s²) per sensor,
    ``inf`` where the noise does not grow."""
    from scipy.ndimage import uniform_filter1d

    a = [np.abs(np.gradient(uniform_filter1d(f.u, 5, axis=0), float(np.median(np.diff(f.t))), axis=0)).mean()
         for f in flights]
    A = np.column_stack([np.ones(len(a)), np.square(a)])
    (b0, b1), *_ = np.linalg.lstsq(A, np.square([_noise(f) for f in flights]), rcond=None)
    return {name: float("inf") if g <= 0 else float(np.sqrt(max(c, 0.0) / g))
            for (name, _), c, g in zip(SENSORS, b0, b1)}


def _by_trajectory(by: Mapping[str, Sequence[Mapping[str, float]]], *coefficients: str
                   ) -> dict[str, dict[str, float]]:
    """Each trajectory's figures averaged over its runs, each of ``coefficients`` (a name with its
    unit in brackets) first, each with the half-width of its 95 % interval over the runs
    (Student's t)."""
    out = {}
    for t, runs in by.items():
        mean = {k: float(np.mean([r[k] for r in runs])) for k in runs[0]}
        head = {}
        for coefficient in coefficients:
            name, unit = coefficient.split(" [")
            c = np.array([r[coefficient] for r in runs])
            hw = half_width(c.std(ddof=1) / np.sqrt(len(c)), len(c)) if len(c) > 1 else float("nan")
            head.update({coefficient: mean.pop(coefficient), f"{name}, 95 % half-width over the runs [{unit}": hw})
        out[t] = {**head, **mean}
    return out


# Hz: the yaw loop's reach. The Mellinger yaw-rate gain over the body's yaw inertia (kw_z / J_z,
# 26 rad/s) puts its bandwidth at about 4 Hz; the rotors' first-order response (20-60 ms) and the
# IMU's filters take its phase beyond that
YAW_SWING_SPLIT = 4.0


def yaw_reaction(flights: Sequence[Flight], vehicle: Vehicle, window: int = 15, order: int = 3
                 ) -> dict[str, dict[str, float]]:
    """How much of the nominal model's yaw torque residual is the rotors' reaction to their own
    acceleration, ``-J_r sum_i s_i dOmega_i/dt`` (``s_i`` the spin directions): per trajectory,
    averaged over its runs, the least-squares ``J_r`` (kg m²) of each flight's yaw residual on
    that sum (with the half-width of its 95 % interval over the runs, Student's t), their
    correlation, the sum's std (rad/s², the rotors' yaw-differential acceleration) and the share
    of the sum's power above :data:`YAW_SWING_SPLIT` (%, Welch's estimate): a swing the yaw loop
    answers sits below it, one faster than the loop above. The rotor speeds are differentiated
    by the same Savitzky-Golay filter as the body rates, so that the filter's own attenuation
    cancels in ``J_r``."""
    return _yaw_reaction(flights, _residuals(flights, vehicle, window, order), window, order)


def _yaw_reaction(flights: Sequence[Flight], residuals: Sequence[np.ndarray], window: int, order: int
                  ) -> dict[str, dict[str, float]]:
    from scipy.signal import savgol_filter, welch

    spin = np.asarray(dynamics.SPIN)
    by: dict[str, list[dict[str, float]]] = {}
    for f, r in zip(flights, residuals):
        y = r[:, 5]
        dt = float(np.median(np.diff(f.t)))
        x = -(savgol_filter(f.u, window, order, deriv=1, delta=dt, axis=0) @ spin)[EDGE:-EDGE]
        x, y = x - x.mean(), y - y.mean()
        fr, p = welch(x, fs=1 / dt, nperseg=min(512, len(x)), detrend=False)
        by.setdefault(f.trajectory, []).append({
            "J_r [kg m²]": float(x @ y / (x @ x)), "correlation": float(np.corrcoef(x, y)[0, 1]),
            "yaw-differential rotor acceleration [rad/s² std]": float(x.std()),
            f"yaw-differential rotor acceleration above {YAW_SWING_SPLIT:g} Hz [% of its power]":
                float(100 * p[fr > YAW_SWING_SPLIT].sum() / p.sum())})
    return _by_trajectory(by, "J_r [kg m²]")


def climb_drag(flights: Sequence[Flight], vehicle: Vehicle, window: int = 15, order: int = 3
               ) -> dict[str, dict[str, float]]:
    """How much of the nominal model's thrust residual is a drag along the body's z axis, linear
    in the rotor speeds and the body velocity, ``F_z = -K_z (sum_i Omega_i) v_z`` (Förster's
    induced drag): per trajectory, averaged over its runs, the least-squares ``K_z`` (kg/rad) of
    each flight's thrust residual on ``-(sum_i Omega_i) v_z`` (with the half-width of its 95 %
    interval over the runs, Student's t), their correlation, and ``v_z``'s std (m/s, the body-z
    velocity). The regressor is smoothed by the same Savitzky-Golay filter as the accelerometer,
    so that the filter cancels in ``K_z``."""
    return _climb_drag(flights, _residuals(flights, vehicle, window, order), window, order)


def _climb_drag(flights: Sequence[Flight], residuals: Sequence[np.ndarray], window: int, order: int
                ) -> dict[str, dict[str, float]]:
    import torch
    from scipy.signal import savgol_filter

    from nanosysid.so3 import quat_to_rotmat

    by: dict[str, list[dict[str, float]]] = {}
    for f, r in zip(flights, residuals):
        y = r[:, 2]
        R = quat_to_rotmat(torch.from_numpy(f.y[:, 6:10])).numpy()
        v_z = np.einsum("ti,ti->t", R[:, :, 2], f.y[:, 3:6])  # the world velocity on the body's z axis
        x = -savgol_filter(f.u.sum(1) * v_z, window, order, axis=0)[EDGE:-EDGE]
        x, y = x - x.mean(), y - y.mean()
        by.setdefault(f.trajectory, []).append({
            "K_z [kg/rad]": float(x @ y / (x @ x)), "correlation": float(np.corrcoef(x, y)[0, 1]),
            "body-z velocity [m/s std]": float(v_z[EDGE:-EDGE].std())})
    return _by_trajectory(by, "K_z [kg/rad]")


# Hz: the corner of the zero-phase low-pass drag_moment reads the roll and pitch residual through:
# below it the rig's residual is mostly a moment of the body's air speed, above it the rotors'
# fluctuation and the gyro's noise through the derivative
DRAG_MOMENT_BAND = 1.0


def drag_moment(flights: Sequence[Flight], vehicle: Vehicle, window: int = 15, order: int = 3
                ) -> dict[str, dict[str, float]]:
    """How much of the nominal model's slow roll and pitch torque residual is a moment linear in
    the rotor speeds and the body velocity, ``tau = (E_x S_y, -E_y S_x)``, ``S = (sum_i Omega_i)
    v_B`` (each rotor's disc flapping back from its air speed tilts its thrust, whose line then
    misses the centre of mass: Mahony, Kumar and Corke 2012): per trajectory, averaged over its
    runs, the least-squares ``E_x`` and ``E_y`` (kg m/rad) of each flight's residual on ``S_y`` and
    ``-S_x``, both through a zero-phase second-order low-pass at :data:`DRAG_MOMENT_BAND` Hz (with
    the half-widths of their 95 % intervals over the runs, Student's t), and their correlations.
    ``S`` is smoothed by the same Savitzky-Golay filter as the gyro's derivative, so that the
    filter cancels."""
    return _drag_moment(flights, _residuals(flights, vehicle, window, order), window, order)


def _drag_moment(flights: Sequence[Flight], residuals: Sequence[np.ndarray], window: int, order: int
                 ) -> dict[str, dict[str, float]]:
    import torch
    from scipy.signal import butter, savgol_filter, sosfiltfilt

    from nanosysid.so3 import quat_to_rotmat

    by: dict[str, list[dict[str, float]]] = {}
    for f, r in zip(flights, residuals):
        R = quat_to_rotmat(torch.from_numpy(f.y[:, 6:10])).numpy()
        v_b = np.einsum("tji,tj->ti", R, f.y[:, 3:6])
        S = savgol_filter(f.u.sum(1)[:, None] * v_b, window, order, axis=0)[EDGE:-EDGE]
        sos = butter(2, DRAG_MOMENT_BAND, fs=1 / float(np.median(np.diff(f.t))), output="sos")
        row = {}
        for axis, x, y in (("x", S[:, 1], r[:, 3]), ("y", -S[:, 0], r[:, 4])):
            x, y = sosfiltfilt(sos, x - x.mean()), sosfiltfilt(sos, y - y.mean())
            row[f"E_{axis} [kg m/rad]"] = float(x @ y / (x @ x))
            row[f"correlation, {axis}"] = float(np.corrcoef(x, y)[0, 1])
        by.setdefault(f.trajectory, []).append(row)
    return _by_trajectory(by, "E_x [kg m/rad]", "E_y [kg m/rad]")


# Hz: the edges of the bands torque_bands splits the roll and pitch residual into: a flight's slow
# drift, the trajectories' band, the rotors' fluctuation, and above it mostly the gyro's noise
# through the derivative
TORQUE_BAND_EDGES = (0.1, 0.8, 3.2)
# the bands' names, lowest first: the report's columns and the figures' keys
TORQUE_BANDS = (f"below {TORQUE_BAND_EDGES[0]:g} Hz",
                *(f"{a:g}-{b:g} Hz" for a, b in zip(TORQUE_BAND_EDGES, TORQUE_BAND_EDGES[1:])),
                f"above {TORQUE_BAND_EDGES[-1]:g} Hz")


def torque_bands(flights: Sequence[Flight], vehicle: Vehicle, window: int = 15, order: int = 3
                 ) -> dict[str, dict[str, float]]:
    """Where in frequency the nominal model's roll and pitch torque residual lies: per trajectory,
    averaged over its runs, the residual's RMS (mN m) in each band between
    :data:`TORQUE_BAND_EDGES` (the flight's mean out; a band is the difference of two
    zero-phase fourth-order Butterworth low-passes, so the bands add up to the residual)."""
    return _torque_bands(flights, _residuals(flights, vehicle, window, order))


def _torque_bands(flights: Sequence[Flight], residuals: Sequence[np.ndarray]) -> dict[str, dict[str, float]]:
    from scipy.signal import butter, sosfiltfilt

    edges = TORQUE_BAND_EDGES
    by: dict[str, list[dict[str, float]]] = {}
    for f, r in zip(flights, residuals):
        r = r[:, 3:5]
        r = 1e3 * (r - r.mean(axis=0))
        fs = 1 / float(np.median(np.diff(f.t)))
        low = [np.zeros_like(r)] + [sosfiltfilt(butter(4, e, fs=fs, output="sos"), r, axis=0) for e in edges] + [r]
        by.setdefault(f.trajectory, []).append({
            f"{ch} residual {name} [mN·m RMS]": float(np.sqrt(np.mean((low[k + 1][:, c] - low[k][:, c]) ** 2)))
            for c, ch in enumerate(("tau_x", "tau_y")) for k, name in enumerate(TORQUE_BANDS)})
    return {t: {k: float(np.mean([r[k] for r in runs])) for k in runs[0]} for t, runs in by.items()}


def analyses(flights: Sequence[Flight], vehicle: Vehicle, window: int = 15, order: int = 3) -> dict[str, Any]:
    """One side of the comparison from a single pass over the nominal model's residual:
    :func:`world_figures` under ``figures``, then ``noise_law``, ``yaw_reaction``, ``climb_drag``,
    ``drag_moment`` and ``torque_bands``, each as its function gives it."""
    r = _residuals(flights, vehicle, window, order)
    return {"figures": _world_figures(flights, r, vehicle.gravity), "noise_law": noise_law(flights),
            "yaw_reaction": _yaw_reaction(flights, r, window, order),
            "climb_drag": _climb_drag(flights, r, window, order), "drag_moment": _drag_moment(flights, r, window, order),
            "torque_bands": _torque_bands(flights, r)}


def compare(world: Mapping[str, Mapping[str, float]], real: Mapping[str, Mapping[str, float]],
            lags: tuple[float, float], tolerance: float = TOLERANCE) -> dict[str, Any]:
    """Every figure of the world's beside the real flights', its ratio, and the ones off by more
    than ``tolerance``; ``lags``: the motor lag (s) of the world's session and the real one's."""
    rows = []
    for t in sorted(set(world) & set(real)):
        for k in real[t]:
            w, r = world[t][k], real[t][k]
            ratio = w / r if r else float("inf")
            rows.append({"trajectory": t, "figure": k, "world": w, "real": r, "ratio": ratio,
                         "off": bool(abs(ratio - 1) > tolerance)})
    lag_ratio = lags[0] / lags[1] if lags[1] else float("inf")
    rows.append({"trajectory": "all", "figure": "motor lag [ms]", "world": 1e3 * lags[0], "real": 1e3 * lags[1],
                 "ratio": lag_ratio, "off": bool(abs(lag_ratio - 1) > tolerance)})
    return {"tolerance": tolerance, "rows": rows, "off": [r for r in rows if r["off"]]}


# What is known of why a kind of figure is off: where its value in the world comes from
WHY = {
    "rotor speed noise": "set at the rig's level after the data chain, growing with the rotors' motion by the "
                         "rig's own law (`sim.flight.noise.rotor`, `vibration_ref`; the law's table below): the "
                         "world's Melon moves its rotors less than the rig's (its rotors' mean |dΩ/dt| about 600 "
                         "rad/s² against the rig's 730-810), in the transients the motion rows give",
    "accelerometer noise": "set at the rig's level after the data chain, growing with the rotors' motion by the "
                           "rig's own law (`sim.flight.noise.accel`, `vibration_ref`; the law's table below): the "
                           "world's Melon moves its rotors less than the rig's (its rotors' mean |dΩ/dt| about 600 "
                           "rad/s² against the rig's 730-810), in the transients the motion rows give",
    "noise": "set at the rig's level after the data chain, growing with the rotors' motion (`sim.flight.noise`, "
             "`vibration_ref`; the law's table below): the rig's gyro noise follows how far its four rotors' speeds "
             "part more than how fast they move (over its flights, r 0.77 against 0.39), and in its Melon's "
             "transients they part further than the world's (193-202 rad/s between the fastest and the slowest "
             "rotor, on average over a flight, against 144-159)",
    "spread": "the world's flights differ only in their random draws (the turbulence, the thrust fluctuation, the "
              "accelerometer's bias at the rig's size): its slow roll turbulence (0.4 Hz, the rig's band) leaves "
              "each flight a mean torque of about 0.1 mN m, above the rig's roll figure (the rig's roll residual "
              "has little power below 0.1 Hz: the section 'The roll and pitch residual's bands'); the rig's mean "
              "pitch and yaw torques move together between groups of consecutive flights (the vehicle changed "
              "between them: its centre of mass moved by a few tenths of a millimetre when the battery was "
              "changed, most likely), which the world, one vehicle with one centre of mass for all its flights, "
              "does not have",
    "residual": "the world's effects have one size for every trajectory: its rotor drag is the rig's (K_xy), its "
                "turbulence torque the rig's residual per axis, its turbulence force and thrust fluctuation sized "
                "so that the physics row matches the paper's (reports/sim/stats.md); the rig's residual varies "
                "between trajectories more than that (its Square's thrust residual is the largest, its Random's "
                "yaw residual the smallest), as effects the world lacks would make it; the residual also carries "
                "the rotor speeds' noise through the nominal wrench, larger on the rig's Square than on the world's; "
                "the rig's roll and pitch residual is mostly a drag moment, which grows with the speed and is "
                "largest on its fastest flights, where the world's is mostly a turbulence of one size (the "
                "figure 'median frequency')",
    "tau_z": "the rig's yaw residual is the rotors' reaction to their own acceleration (the section 'The yaw "
             "residual' below: on the rig it follows the rotors' yaw-differential acceleration with a rotor "
             "inertia below the world's (the world's outside three of its four trajectories' 95 % intervals), and "
             "its rotors swing in yaw faster and harder than the world's); the world's is mostly its "
             "rotors' drag-torque fluctuation (`unsteady_thrust`, 3 Hz) and its yaw turbulence, which the controller "
             "answers through the rotor speeds, a band below the rig's. On the rig's Chirp most of the rotors' "
             "yaw-differential swing lies above 4 Hz, beyond the reach of a yaw loop of the firmware's gains (the "
             "section's last column), where the world's lies mostly below: that part is not the controller's answer "
             "to a yaw torque, and the rig's flights do not tell what drives it",
    "median frequency": "the rig's roll and pitch residual below 1 Hz is a drag moment, linear in the rotor speeds "
                        "and the body velocity (the section 'The slow roll and pitch residual and the air speed' "
                        "below: correlations 0.93-0.98 on every trajectory, pitch above roll; its hypotheses' "
                        "report, reports/rig/hypotheses, names a drag moment held out): "
                        "it follows the flight's velocity, so it lies in the trajectories' band and rises with "
                        "their pace (the Square's moves of 1 m in 1 s put it near 1 Hz). The world's drag moment "
                        "is only its rotors' drag at their hubs, a fifth of the rig's (the same section), and its "
                        "roll and pitch residual is mostly its slow turbulence "
                        "(0.4 Hz, random in time) and its thrust fluctuation (3 Hz): the section 'The roll and pitch "
                        "residual's bands'",
    "F_z": "the rig's thrust residual follows its climb rate (the section 'The thrust residual and the climb "
           "rate' below): a drag along the body's z axis, linear in the rotor speeds and the body velocity, which "
           "the world has at the rig's size (its K_z reads as the rig's there); the rest of the world's thrust "
           "residual is its thrust fluctuation (3 Hz) and turbulence force, sized so that the physics row matches "
           "the paper's (reports/sim/stats.md). On the rig's Random the climb drag carries more of the residual "
           "than on the world's (their correlations in that section), so it sits lower in frequency; the rig's "
           "Square, with its climbs and descents of 1 m within a second and its rotors swinging the most, has a "
           "thrust residual beyond the climb drag, larger and faster than any of the world's",
    "motor lag": "the world's rotor speeds are recorded as they turn and its IMU reads through the firmware's "
                 "filters (`sim.recorder`), so its motor readings lead the accelerometer by that filter's delay "
                 "alone, as the rig's do; a telemetry delay (`sim.effects.telemetry_delay`) adds to it",
    "motion": "the simulator flies the paper's Square and Chirp as published and the rig's logged Random and "
              "Melon, with a position loop stiffer than the firmware's default (`sim.flight.gains`); the rig's "
              "Melon rolls and yaws more in its two transients: in its first two seconds, the climb from the "
              "takeoff height with its four rotors level at full throttle (the attitude loop left without "
              "authority), 1.2-2.7 rad/s of roll and 0.5-1.1 of yaw against the world's 0.2-0.5 and 0.2-0.6; in "
              "its last five, after its setpoint stops dead at the circle's end, 0.6-0.8 and 0.4-0.5 against "
              "0.3 and 0.05. In the climb's braking the rig's controller cuts its rotors to idle and they spin down "
              "slowly (GRAFE's in-flight fit of the rotor's response 50 ms, drone-models' 57-65 ms; the world's "
              "`sim.flight.motor_tau` 20 ms): flown with 55 ms rotors, the world's Melon starts as the rig's, but "
              "its attitude loop then rings faster than the rig's on every trajectory (the gyro's white noise "
              "above the rig's) and the Square no longer flies with a slow lag above 0.3 of the wrench",
}


def _why(figure: str) -> str:
    if figure.startswith(("tau_z residual [", "tau_z residual median")):
        return WHY["tau_z"]
    if figure.startswith(("F_z residual [", "F_z residual median")):
        return WHY["F_z"]
    for key in ("spread", "median frequency", "rotor speed noise", "accelerometer noise", "noise", "residual",
                "motor lag"):
        if key in figure:
            return WHY[key]
    return WHY["motion"]


def _bands_table(part: Mapping[str, Mapping[str, Mapping[str, float]]], title: str, text: str) -> list[str]:
    """:func:`torque_bands`' section: a row per trajectory and axis, a column pair per band."""
    L = [f"## {title}", "", f"{text}; RMS in mN·m, each averaged over a trajectory's runs:", "",
         "| trajectory | axis | " + " | ".join(f"{b}, world | {b}, real" for b in TORQUE_BANDS) + " |",
         "|---|---|" + "---|---|" * len(TORQUE_BANDS)]
    for t in sorted(set(part["world"]) & set(part["real"])):
        for ch in ("tau_x", "tau_y"):
            cells = [f"{part[side][t][f'{ch} residual {b} [mN·m RMS]']:.3g}" for b in TORQUE_BANDS
                     for side in ("world", "real")]
            L.append(f"| {t} | {ch} | " + " | ".join(cells) + " |")
    return L + [""]


def markdown(result: Mapping[str, Any]) -> str:
    """The comparison as a report: every figure off by more than the tolerance, then the table."""
    tol = result["tolerance"]
    L = ["# The simulated world against the real flights", "",
         f"The default world's flights beside the rig's, figure by figure (each averaged over a trajectory's runs); "
         f"{len(result['off'])} of {len(result['rows'])} figures are more than {100 * tol:.0f} % off.", "",
         "## Off by more than the tolerance", "", "| trajectory | figure | world | real | ratio | why |",
         "|---|---|---|---|---|---|"]
    for r in result["off"]:
        L.append(f"| {r['trajectory']} | {r['figure']} | {r['world']:.4g} | {r['real']:.4g} | {r['ratio']:.2f} | "
                 f"{_why(r['figure'])} |")
    L += ["", "The world's gyro, accelerometer and rotor-speed noise are set at the rig's levels after the data chain, "
          "growing with how much the rotors move, and its IMU reads through the firmware's filters. Its effects and "
          "their bands are not fitted to these figures: each "
          "moves the benchmark's pattern on the simulated world (reports/sim/stats.md), which is what the world "
          "is tuned to show.", ""]
    if "noise_law" in result:
        law = result["noise_law"]
        L += ["## How the noise grows with the rotors' motion", "",
              "Each sensor's noise over the flights as `n0 sqrt(1 + (a / ref)²)`, `a` a flight's rotors' mean "
              "|dΩ/dt| (least squares over the flights; a larger `ref` grows more slowly):", "",
              "| sensor | world's ref [rad/s²] | real ref [rad/s²] |", "|---|---|---|"]
        L += [f"| {k} | {law['world'][k]:.0f} | {law['real'][k]:.0f} |" for k in law["real"]]
        L.append("")
    sections = (("yaw_reaction", "The yaw residual",
                 "The nominal model's yaw torque residual regressed, flight by flight, on the rotors' reaction to their "
                 "own acceleration, `-J_r sum_i s_i dΩ_i/dt` (the world's rotor inertia is "
                 f"{result.get('rotor_inertia', float('nan')):.3g} kg m²)"),
                ("climb_drag", "The thrust residual and the climb rate",
                 "The nominal model's thrust residual regressed, flight by flight, on a drag along the body's z axis "
                 "linear in the rotor speeds and the body velocity, `-K_z (sum_i Ω_i) v_z` (Förster's induced drag; "
                 f"the world's K_z is {result.get('rotor_drag_z', float('nan')):.3g} kg/rad, its body drag adds a "
                 "little)"),
                ("drag_moment", "The slow roll and pitch residual and the air speed",
                 f"The nominal model's roll and pitch torque residual below {DRAG_MOMENT_BAND:g} Hz regressed, flight by "
                 "flight, on a moment linear in the rotor speeds and the body velocity, `(E_x S_y, -E_y S_x)`, `S = "
                 "(sum_i Ω_i) v_B` (the rotors' discs flapping back from their air speed; the world's is only its "
                 f"rotors' drag at their hubs, {result.get('hub_moment', float('nan')):.3g} kg m/rad on each axis)"),
                ("torque_bands", "The roll and pitch residual's bands",
                 "The nominal model's roll and pitch torque residual split into bands (a flight's slow drift, the "
                 "trajectories' band, the rotors' fluctuation, and above it mostly the gyro's noise through the "
                 "derivative); the world's comes from its turbulence and thrust fluctuation, random in time, the "
                 "rig's from whatever makes it"))
    for key, title, text in sections:
        if key not in result:
            continue
        part = result[key]
        if key == "torque_bands":
            L += _bands_table(part, title, text)
            continue
        keys = list(next(iter(part["real"].values())))
        L += [f"## {title}", "", f"{text}; each figure averaged over a trajectory's runs:", "",
              "| trajectory | " + " | ".join(f"{k}, world | {k}, real" for k in keys) + " |",
              "|---|" + "---|---|" * len(keys)]
        for t in sorted(set(part["world"]) & set(part["real"])):
            L.append(f"| {t} | " + " | ".join(f"{part['world'][t][k]:.3g} | {part['real'][t][k]:.3g}" for k in keys)
                     + " |")
        L.append("")
    L += ["## Every figure", "", "| trajectory | figure | world | real | ratio |", "|---|---|---|---|---|"]
    for r in result["rows"]:
        L.append(f"| {r['trajectory']} | {r['figure']} | {r['world']:.4g} | {r['real']:.4g} | {r['ratio']:.2f}"
                 f"{' ✗' if r['off'] else ''} |")
    return "\n".join(L) + "\n"
