"""The simulated world against the real flights, figure by figure: per trajectory the motion's
statistics (speed, acceleration, tilt, body rates), the measurement noise of each signal, and the
nominal model's force and torque residual (its size and its band); over all flights, how far each
flight's mean residual moves from flight to flight, and the motor lag of each session. Every
figure more than :data:`TOLERANCE` off the real flights' is listed, with what is known of why."""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from nanosysid.dataio import Flight
from nanosysid.discover.fit import EDGE, measured_wrench, nominal_wrench
from nanosysid.discover.stats import spread
from nanosysid.effects import CHANNELS
from nanosysid.report.stats import flight_stats
from nanosysid.vehicle import Vehicle

__all__ = ["TOLERANCE", "world_figures", "compare", "markdown"]

TOLERANCE = 0.25


def _white(a: np.ndarray) -> np.ndarray:
    """Std of the white noise on each column (the median absolute second difference, which a
    slow signal barely moves: ``Var(x'') = 6 sigma²`` for white noise)."""
    return np.median(np.abs(np.diff(a, n=2, axis=0)), axis=0) / 0.6745 / np.sqrt(6.0)


def _median_frequency(x: np.ndarray, dt: float) -> float:
    """The frequency (Hz) below which half of the power of ``x`` lies."""
    from scipy.signal import welch

    f, p = welch(x - x.mean(), fs=1 / dt, nperseg=min(1024, len(x)))
    c = np.cumsum(p)
    return float(f[np.searchsorted(c, 0.5 * c[-1])])


def _residual(f: Flight, vehicle: Vehicle, window: int, order: int) -> np.ndarray:
    """The nominal model's force (N) and torque (N m) residual ``(T', 6)``, the edges of the
    derivative's window left out."""
    return (measured_wrench(f, vehicle, window, order) - nominal_wrench(f.u, vehicle))[EDGE:-EDGE]


def _flight(f: Flight, r: np.ndarray, gravity: float) -> dict[str, float]:
    s = flight_stats(f, gravity)
    out = {"v_mean [m/s]": s["v_mean"], "v_max [m/s]": s["v_max"], "a_max [m/s²]": s["a_max"],
           "tilt_max [°]": s["tilt_max"]}
    for i, ax in enumerate("xyz"):
        out[f"rate_{ax} RMS [rad/s]"] = float(np.sqrt(np.mean(f.y[:, 10 + i] ** 2)))
    acc = np.column_stack([f.extra[c] for c in ("ax_body", "ay_body", "az_body")])
    for name, values, unit in (("gyro", f.y[:, 10:13], "rad/s"), ("accelerometer", acc, "m/s²"),
                               ("rotor speed", f.u, "rad/s")):
        out[f"{name} noise [{unit}]"] = float(np.median(_white(values)))
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
    by: dict[str, list[dict[str, float]]] = {}
    means = []
    for f in flights:
        r = _residual(f, vehicle, window, order)
        means.append(r.mean(axis=0))
        by.setdefault(f.trajectory, []).append(_flight(f, r, vehicle.gravity))
    out = {t: {k: float(np.mean([r[k] for r in runs])) for k in runs[0]} for t, runs in by.items()}
    if len(means) > 1:
        s = 1e3 * spread(np.asarray(means))[0]
        out["all"] = {f"{ch} residual, spread of the flights' means [{'mN' if c < 3 else 'mN·m'}]": float(s[c])
                      for c, ch in enumerate(CHANNELS)}
    return out


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
    "rotor speed noise": "set at the rig's level after the data chain, growing with how much the rotors move "
                         "(`sim.flight.noise.rotor`, `vibration_ref`): where it is off, the world's rotors move more "
                         "or less than the rig's on that trajectory (its Melon leaves and brakes more gently, its "
                         "Square's corners move the rotors more)",
    "accelerometer noise": "set at the rig's level after the data chain, growing with how much the rotors move "
                           "(`sim.flight.noise.accel`, `vibration_ref`): where it is off, the world's rotors move "
                           "more or less than the rig's on that trajectory (its Melon leaves and brakes more gently, "
                           "its Square's corners move the rotors more)",
    "noise": "set at the rig's level after the data chain, growing with how much the rotors move "
             "(`sim.flight.noise`, `vibration_ref`): where it is off, the world's rotors move more or less than "
             "the rig's on that trajectory (its Melon leaves and brakes more gently, its Square's corners move the "
             "rotors more); one law of the rotors' acceleration does not give the rig's level on every trajectory",
    "spread": "the world's flights differ only in their random draws (the turbulence, the thrust fluctuation, the "
              "accelerometer's bias at the rig's size): its slow roll turbulence (0.4 Hz, the rig's band) leaves "
              "each flight a mean torque of about 0.1 mN m, above the rig's roll figure; the rig's mean pitch and "
              "yaw torques move together between groups of consecutive flights (the vehicle changed between them: "
              "its centre of mass moved by a few tenths of a millimetre when the battery was changed, most "
              "likely), which the world, one vehicle with one centre of mass for all its flights, does not have",
    "residual": "the world's effects have one size for every trajectory: its rotor drag is the rig's (K_xy), its "
                "turbulence torque the rig's residual per axis, its turbulence force and thrust fluctuation sized "
                "so that the physics row matches the paper's (reports/sim/stats.md); the rig's residual varies "
                "between trajectories more than that (its Square's thrust residual is the largest, its Random's "
                "yaw residual the smallest), as effects the world lacks would make it",
    "median frequency": "the world's time-varying effects have corners of 1 Hz (the turbulence's force), 0.4 Hz "
                        "(its roll and pitch torque, the rig's band), 3 Hz (its yaw torque) and 3 Hz (the thrust "
                        "fluctuation, which carries the world's thrust residual to about 1 Hz); the rig's force "
                        "residual sits lower (0.3-0.5 Hz), its yaw torque residual higher (2-3 Hz)",
    "motor lag": "the world delays the recorded rotor speeds by its telemetry delay (30 ms), which the sync stage "
                 "must find; the rig's logs lag by a few ms, as the sync stage measures them",
    "motion": "the simulator flies the paper's Square and Chirp as published and the rig's logged Random and "
              "Melon, with a position loop stiffer than the firmware's default (`sim.flight.gains`); the rig's "
              "Melon rolls and yaws more in its two transients: in its first two seconds, the climb from the "
              "takeoff height with its four rotors level at full throttle (the attitude loop left without "
              "authority), 1.2-2.7 rad/s of roll and 0.5-1.1 of yaw against the world's 0.2-0.5 and 0.2-0.6; in "
              "its last five, after its setpoint stops dead at the circle's end, 0.6-0.8 and 0.4-0.5 against "
              "0.3 and 0.05",
}


def _why(figure: str) -> str:
    for key in ("spread", "median frequency", "rotor speed noise", "accelerometer noise", "noise", "residual",
                "motor lag"):
        if key in figure:
            return WHY[key]
    return WHY["motion"]


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
          "growing with how much the rotors move. Its effects, their bands and the telemetry delay are not fitted to "
          "these figures: each "
          "moves the benchmark's pattern on the simulated world (reports/sim/stats.md), which is what the world "
          "is tuned to show.", "",
          "## Every figure", "", "| trajectory | figure | world | real | ratio |", "|---|---|---|---|---|"]
    for r in result["rows"]:
        L.append(f"| {r['trajectory']} | {r['figure']} | {r['world']:.4g} | {r['real']:.4g} | {r['ratio']:.2f}"
                 f"{' ✗' if r['off'] else ''} |")
    return "\n".join(L) + "\n"
