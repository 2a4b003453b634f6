"""The low-frequency roll/pitch torque's hypotheses, tested apart.

The roll and pitch torque the rotor model misses lies mostly below 1 Hz (the benchmark paper's
open question). The literature offers several explanations, each a library entry of
:mod:`nanosysid.effects` (with its source there) or a property of the data:

- ``cg_offset``: the centre of mass off the rotors' centre; the thrust torques roll and pitch in
  a fixed body direction, in hover as in flight. Also measured per flight from the flight's own
  take-off hold (:func:`hold_offset`), outside the scored segment: ``cg_offset@hold``;
- ``induced_drag_moment`` / ``drag_moment``: the rotors' (or the airframe's) drag acting off the
  centre of mass, proportional to the body velocity: zero in hover, its sign following the
  direction of flight;
- ``rotor_spread``: rotors of unequal coefficients, each rotor's share proportional to its own
  thrust;
- ``slow_actuation``: part of each rotor's wrench lagging its speed;
- ``battery_thrust``: the rotors' wrench scaling with the battery voltage (a trend over the
  flight);
- ``air``: the vehicle's own downwash and the arena's air, which do not repeat between runs of
  one reference.

Each hypothesis is put to four tests on the training flights' roll/pitch torque residual,
low-passed (zero phase) at :data:`CUTOFF`: its coefficients per flight (a 95 % interval from the
flights as independent repeats); its held-out share of the residual's power (fitted on the other
references' flights); the hover check (what it predicts where the vehicle barely moves, against
what is measured there); and whether the residual, and what the hypothesis leaves of it, repeat
between runs of one reference. :func:`verdict` names what the data support and what they exclude.

Example::

    data = torque_data(flights, vehicle)
    result = tested_apart(data, reference_correlation(flights, data), vehicle=vehicle)
    result["named"]      # e.g. ['induced_drag_moment', 'cg_offset'], ['air'] or []
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np
import torch

from nanosysid import effects
from nanosysid.dataio import Flight
from nanosysid.discover.fit import EDGE, flight_data, nominal_wrench
from nanosysid.discover.sources import reference_pairs
from nanosysid.identify import body_torque
from nanosysid.vehicle import Vehicle

__all__ = ["HYPOTHESES", "HOLD", "AIR", "CUTOFF", "MIN_SHARE", "TIE", "REPEAT", "TorqueData", "torque_data",
           "MIN_GAIN", "lowpass", "fit", "per_flight", "held_out", "hover_check",
           "reference_correlation", "hold_offset",
           "tested_apart", "verdict"]

# the library entries put to the tests, in the order the report lists them
HYPOTHESES = ("cg_offset", "induced_drag_moment", "drag_moment", "rotor_spread", "slow_actuation", "battery_thrust")
HOLD = "cg_offset@hold"  # the centre-of-mass offset measured per flight from its take-off hold
AIR = "air"
CUTOFF = 1.0  # Hz: the band of the paper's unexplained torque lies below it
# a hypothesis explaining less than this share of the held-out residual's power explains nothing
# worth naming (the roll/pitch residual's power above the noise floor is what is asked about)
MIN_SHARE = 0.2
# a further hypothesis must add at least this share held out to the ones named before it
MIN_GAIN = 0.05
# supported hypotheses whose held-out shares lie within this of the best are not told apart by
# these flights; the one with the fewest coefficients is named
TIE = 0.05
# the residual repeats between runs of one reference when the runs' residuals correlate above this
REPEAT = 0.5
# a hover sample: the horizontal speed (m/s) and the roll/pitch rate (rad/s) below these
HOVER_SPEED, HOVER_RATE = 0.2, 0.5
HOVER_MIN = 50  # samples of hover a flight needs for its hover mean to count
# the hover torque a hypothesis must reproduce to pass the hover check, as a share of the measured
HOVER_SHARE = 0.5
ROLL_PITCH = slice(3, 5)  # the wrench channels tau_x, tau_y


@dataclass
class TorqueData:
    """One flight's low-passed roll/pitch torque residual and every hypothesis' columns.

    Attributes:
        name: The flight's name; ``trajectory`` its reference.
        t: Sample times (s), ``(T,)``.
        r: Residual torque ``(T, 2)`` (N m): tau_x, tau_y measured minus the rotor model's.
        columns: Per hypothesis of :data:`HYPOTHESES`, its columns on tau_x, tau_y ``(T, 2, P)``.
        hover: ``(T,)``, True where the vehicle barely moves.
    """

    name: str
    trajectory: str
    t: np.ndarray
    r: np.ndarray
    columns: dict[str, np.ndarray]
    hover: np.ndarray


def lowpass(a: np.ndarray, dt: float, cutoff: float = CUTOFF) -> np.ndarray:
    """``a`` ``(T, ...)`` through a second-order Butterworth low-pass of ``cutoff`` Hz, forwards and
    backwards (zero phase; a linear filter, so a column's fit is the same before or after it)."""
    from scipy.signal import butter, sosfiltfilt

    sos = butter(2, cutoff, fs=1.0 / dt, output="sos")
    return sosfiltfilt(sos, a, axis=0)


def torque_data(flights: Sequence[Flight], vehicle: Vehicle, *, window: int = 15, order: int = 3,
                cutoff: float = CUTOFF) -> list[TorqueData]:
    """Every flight's :class:`TorqueData` (the residual and columns of
    :func:`nanosysid.discover.fit.flight_data`, no rotor-speed delay, low-passed at ``cutoff``)."""
    out = []
    for f in flights:
        d = flight_data(f, vehicle, 0.0, window=window, order=order)
        dt = float(np.median(np.diff(f.t)))
        y = f.y[EDGE:-EDGE]
        hover = (np.hypot(y[:, 3], y[:, 4]) < HOVER_SPEED) & (np.hypot(y[:, 10], y[:, 11]) < HOVER_RATE)
        cols = {h: lowpass(d.features[h][:, ROLL_PITCH], dt, cutoff) for h in HYPOTHESES}
        out.append(TorqueData(f.name, f.trajectory, d.t, lowpass(d.r[:, ROLL_PITCH], dt, cutoff), cols, hover))
    return out


def _stack(data: Sequence[TorqueData], names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    X = np.concatenate([np.concatenate([d.columns[n] for n in names], axis=-1) for d in data])
    return X.reshape(-1, X.shape[-1]), np.concatenate([d.r for d in data]).reshape(-1)


def _live(X: np.ndarray) -> np.ndarray:
    """The columns that are not all zero (a battery column where no voltage is logged, the lags
    where no history is given)."""
    return np.abs(X).max(axis=0) > 0


def fit(data: Sequence[TorqueData], names: Sequence[str]) -> np.ndarray:
    """Least-squares coefficients ``(P,)`` of the hypotheses ``names`` together on the flights
    ``data`` (tau_x and tau_y alike: both are torques in N m); 0 for a column that is zero
    throughout."""
    X, y = _stack(data, names)
    theta = np.zeros(X.shape[1])
    live = _live(X)
    if live.any():
        scale = np.sqrt((X[:, live] ** 2).mean(axis=0))
        theta[live] = np.linalg.lstsq(X[:, live] / scale, y, rcond=None)[0] / scale
    return theta


def _interval(values: np.ndarray, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    """Mean and half-width of the ``level`` interval of the mean of independent repeats ``(n, ...)``
    (Student's t with n - 1 degrees of freedom)."""
    from scipy.stats import t as student_t

    n = len(values)
    mean = values.mean(axis=0)
    if n < 2:
        return mean, np.full_like(mean, np.inf)
    half = student_t.ppf(0.5 + level / 2, n - 1) * values.std(axis=0, ddof=1) / np.sqrt(n)
    return mean, half


def per_flight(data: Sequence[TorqueData], names: Sequence[str]) -> dict[str, Any]:
    """The hypotheses ``names`` fitted to each flight alone: the coefficients ``(n, P)`` and their
    mean with a 95 % interval from the flights (independent repeats)."""
    thetas = np.stack([fit([d], names) for d in data])
    mean, half = _interval(thetas)
    return {"coefficients": thetas, "mean": mean, "half_width": half}


def _groups(data: Sequence[TorqueData]) -> list[list[int]]:
    """Flights grouped by reference; one flight a group where every flight flies one reference."""
    refs = sorted({d.trajectory for d in data})
    if len(refs) < 2:
        return [[i] for i in range(len(data))]
    return [[i for i, d in enumerate(data) if d.trajectory == r] for r in refs]


def held_out(data: Sequence[TorqueData], names: Sequence[str]) -> dict[str, Any]:
    """The hypotheses ``names``' predictions of each flight, fitted together without its
    reference's flights (runs of one reference would carry a flight's own disturbance pattern
    into its fit), and their share of the residual's power (:func:`_share_of`)."""
    pred: list[np.ndarray | None] = [None] * len(data)
    for group in _groups(data):
        theta = fit([d for i, d in enumerate(data) if i not in group], names)
        for i in group:
            pred[i] = np.concatenate([data[i].columns[n] for n in names], axis=-1) @ theta
    return _share_of(data, pred)


def _share_of(data: Sequence[TorqueData], pred: Sequence[np.ndarray | None]) -> dict[str, Any]:
    """``1 - SSE / SS`` pooled over the flights with a prediction (SS of the residual itself: its
    mean is part of what is to be explained), and per flight."""
    keep = [i for i, p in enumerate(pred) if p is not None]
    sse = np.array([((data[i].r - pred[i]) ** 2).sum() for i in keep])
    ss = np.array([(data[i].r ** 2).sum() for i in keep])
    return {"prediction": list(pred), "share": float(1 - sse.sum() / ss.sum()) if keep else None,
            "flight_shares": [None if p is None else float(1 - ((d.r - p) ** 2).sum() / (d.r ** 2).sum())
                              for d, p in zip(data, pred)]}


def hover_check(data: Sequence[TorqueData], predictions: Mapping[str, Sequence[np.ndarray | None]]) -> dict[str, Any]:
    """The residual torque where the vehicle barely moves: its mean per flight (flights with at
    least :data:`HOVER_MIN` hover samples), the mean over flights with a 95 % interval per axis,
    whether it differs from zero, and per hypothesis the share of it its predictions reproduce
    (``<pred, meas> / |meas|²`` over the flights' hover means). A drag moment vanishes in hover; a
    centre-of-mass offset does not."""
    flights = [i for i, d in enumerate(data) if d.hover.sum() >= HOVER_MIN]
    if not flights:
        return {"flights": 0, "significant": False, "mean": None, "half_width": None, "reproduced": {}}
    meas = np.stack([data[i].r[data[i].hover].mean(axis=0) for i in flights])
    mean, half = _interval(meas)
    reproduced = {}
    for name, pred in predictions.items():
        use = [k for k, i in enumerate(flights) if pred[i] is not None]
        if not use:
            reproduced[name] = None
            continue
        p = np.stack([pred[flights[k]][data[flights[k]].hover].mean(axis=0) for k in use])
        m = meas[use]
        reproduced[name] = float((p * m).sum() / max((m * m).sum(), 1e-300))
    return {"flights": len(flights), "significant": bool(np.any(np.abs(mean) > half)), "mean": mean.tolist(),
            "half_width": half.tolist(), "reproduced": reproduced}


def reference_correlation(flights: Sequence[Flight], data: Sequence[TorqueData]) -> np.ndarray:
    """Per sample of the concatenated ``data``, the sample of its partner run (the same reference,
    :func:`nanosysid.discover.sources.reference_pairs`) at the same time, or -1."""
    return reference_pairs(flights, [d.t for d in data]).index


def _correlation(series: Sequence[np.ndarray], index: np.ndarray) -> float | None:
    """Correlation (about zero) of a signal with its partner runs' at the same times."""
    a = np.concatenate(series)
    ok = index >= 0
    if not ok.any():
        return None
    x, y = a[ok], a[index[ok]]
    return float((x * y).sum() / np.sqrt(max((x * x).sum() * (y * y).sum(), 1e-300)))


def hold_offset(hold: Flight, vehicle: Vehicle, *, window: int = 15, order: int = 3) -> dict[str, Any]:
    """The centre-of-mass offset ``(r_x, r_y)`` (m) a take-off hold gives: the residual roll/pitch
    torque (the gyro's ``J dω/dt + ω × Jω`` minus the rotor model's, smoothed alike) fitted on the
    ``cg_offset`` columns over the hold, with a 95 % interval from its quarters. In a hold the
    controller trims the rotors against whatever constant torque acts; in hover a per-rotor spread
    acts as an offset does, so the hold measures both together."""
    from scipy.signal import savgol_filter

    x, om = (torch.from_numpy(np.ascontiguousarray(a)) for a in (hold.y, hold.u))
    r = (body_torque(hold, vehicle.inertia, window=window, polyorder=order)[:, :2]
         - savgol_filter(nominal_wrench(hold.u, vehicle), window, order, axis=0)[:, ROLL_PITCH])
    X = savgol_filter(effects.features(["cg_offset"], x, om, torch.zeros_like(om), vehicle).numpy()[:, ROLL_PITCH],
                      window, order, axis=0)
    keep = np.arange(EDGE, len(r) - EDGE)
    quarters = np.array_split(keep, 4)
    pieces = [TorqueData(hold.name, hold.trajectory, hold.t[q], r[q], {"cg_offset": X[q]}, np.ones(len(q), bool))
              for q in quarters]
    theta = fit(pieces, ["cg_offset"])
    _, half = _interval(np.stack([fit([p], ["cg_offset"]) for p in pieces]))
    return {"offset": theta.tolist(), "half_width": half.tolist(), "seconds": float(hold.t[keep[-1]] - hold.t[keep[0]])}


def _select(data: Sequence[TorqueData], columns: Mapping[str, int],
            repeats: Mapping[str, float | None], vehicle: Vehicle) -> tuple[list[dict[str, Any]], list[str]]:
    """Forward selection over held-out shares: each round adds the candidate whose joint held-out
    share gains most, if the gain reaches :data:`MIN_SHARE` (first round) or :data:`MIN_GAIN`
    (later), one of its coefficients' intervals from the flights excludes zero, its coefficients
    are physically possible (:meth:`nanosysid.effects.Effect.implausible`), and what it explains repeats between runs of
    one reference (``repeats``: its prediction's correlation with its partner runs', at least
    :data:`REPEAT`; None where no run has a partner). A function of the state and the inputs
    along one reference repeats with it; a fit that follows the controller's answer to a
    disturbance (the rotor speeds' history answers every torque that acts) does not, and where
    the disturbance is itself a function of the state (a drag moment), the history that fits
    the controller's answer to it is no lag. Candidates whose gains lie within :data:`TIE` of
    the best are not told apart: the one with the fewest coefficients (``columns``: each
    candidate's columns that are not zero) is added. Returns the rounds and the names added."""
    named: list[str] = []
    share = 0.0
    rounds = []
    while True:
        gains = {}
        for c in columns:
            if c in named:
                continue
            ho = held_out(data, [*named, c])
            pf = per_flight(data, [*named, c])
            own = slice(len(pf["mean"]) - data[0].columns[c].shape[-1], None)  # the candidate's coefficients
            sig = bool(np.any(np.abs(pf["mean"][own]) > pf["half_width"][own]))
            rep = repeats.get(c)
            gains[c] = {"gain": ho["share"] - share, "share": ho["share"], "significant": sig,
                        "repeats": rep is None or rep >= REPEAT,
                        "implausible": effects.entry(c).implausible(pf["mean"][own], vehicle, pf["half_width"][own])}
        ok = {c: g for c, g in gains.items() if g["significant"] and g["repeats"] and not g["implausible"]
              and g["gain"] >= (MIN_GAIN if named else MIN_SHARE)}
        if not ok:
            rounds.append({"added": None, "gains": gains})
            return rounds, named
        best = max(g["gain"] for g in ok.values())
        tied = [c for c, g in ok.items() if g["gain"] >= best - TIE]
        pick = min(tied, key=lambda c: (columns[c], -ok[c]["gain"]))
        rounds.append({"added": pick, "gains": gains, "not_told_apart": [c for c in tied if c != pick]})
        named.append(pick)
        share = ok[pick]["share"]


def tested_apart(data: Sequence[TorqueData], index: np.ndarray | None = None, *, vehicle: Vehicle,
                    holds: Mapping[str, Sequence[float]] | None = None) -> dict[str, Any]:
    """Every hypothesis' tests, the forward selection and the verdict.

    Args:
        data: The training flights' :func:`torque_data`.
        index: :func:`reference_correlation`'s partner index (None: no runs of one reference).
        vehicle: The nominal vehicle (the bounds of the library's corrections are shares of it).
        holds: Flight name -> its take-off hold's :func:`hold_offset`, for the ``cg_offset@hold``
            hypothesis (None: not tested).
    Returns:
        ``{"hypotheses": {name: record}, "rounds": ..., "named": [...], "hover": ...,
        "repeats": ..., "air": ...}``.
    """
    records: dict[str, dict[str, Any]] = {}
    preds: dict[str, list] = {}
    testable = []
    for name in HYPOTHESES:
        live = _live(_stack(data, [name])[0])
        if not live.any():
            records[name] = {"testable": False, "columns": 0, "params": list(effects.entry(name).params)}
            continue
        testable.append(name)
        ho = held_out(data, [name])
        pf = per_flight(data, [name])
        preds[name] = ho["prediction"]
        records[name] = {"testable": True, "columns": int(live.sum()), "share": ho["share"],
                         "flight_shares": ho["flight_shares"], "mean": pf["mean"].tolist(),
                         "half_width": pf["half_width"].tolist(),
                         "significant": bool(np.any(np.abs(pf["mean"]) > pf["half_width"])),
                         "params": list(effects.entry(name).params)}
    if holds:
        pred = [d.columns["cg_offset"] @ np.asarray(holds[d.name]["offset"]) if d.name in holds else None
                for d in data]
        sh = _share_of(data, pred)
        preds[HOLD] = pred
        own = {d.name: holds[d.name] for d in data if d.name in holds}
        per = np.array([h["offset"] for h in own.values()])
        mean, half = _interval(per)
        # a flight whose hold's own interval excludes the flights' mean offset: the offset moved
        moved = [n for n, h in own.items()
                 if np.any(np.abs(np.asarray(h["offset"]) - mean) > np.asarray(h["half_width"]))]
        records[HOLD] = {"testable": True, "columns": 0, "share": sh["share"], "flight_shares": sh["flight_shares"],
                         "mean": mean.tolist(), "half_width": half.tolist(),
                         "significant": bool(np.any(np.abs(mean) > half)), "params": ["r_x [m]", "r_y [m]"],
                         "per_flight": own, "moved": moved}
    repeats: dict[str, Any] = {"residual": None, "explained": {}, "left": {}}

    def repeat(name: str, pred: Sequence[np.ndarray | None]) -> None:
        if index is not None and all(p is not None for p in pred):
            repeats["explained"][name] = _correlation(pred, index)
            repeats["left"][name] = _correlation([d.r - p for d, p in zip(data, pred)], index)

    if index is not None:
        repeats["residual"] = _correlation([d.r for d in data], index)
    for name, pred in preds.items():
        repeat(name, pred)
    rounds, named = _select(data, {n: records[n]["columns"] for n in testable}, repeats["explained"], vehicle)
    share = None
    if named:
        ho = held_out(data, named)
        preds["named"], share = ho["prediction"], ho["share"]
        repeat("named", preds["named"])
    if holds and named and all(p is not None for p in preds[HOLD]):
        # the hold's offsets taken as known, the named hypotheses refitted on what they leave: the
        # share of the residual both explain together, beside the named ones' alone
        rest = [dataclasses.replace(d, r=d.r - p) for d, p in zip(data, preds[HOLD])]
        both = [h + p for h, p in zip(preds[HOLD], held_out(rest, named)["prediction"])]
        together = _share_of(data, both)["share"]
        records[HOLD]["with_named"] = together
        records[HOLD]["gain"] = together - _share_of(data, preds["named"])["share"]
        preds["named+hold"] = both
    hover = hover_check(data, preds)
    return {**verdict(records, rounds, named, hover, repeats), "share": share}


def verdict(records: dict[str, dict[str, Any]], rounds: list[dict[str, Any]], named: list[str],
            hover: dict[str, Any], repeats: dict[str, Any]) -> dict[str, Any]:
    """Each hypothesis ``named`` (in the selection's order), ``not told apart`` from a named one,
    ``excluded`` (with the figures that exclude it) or ``untestable``; the hover check of the named
    set; and ``air``: supported where what the named hypotheses leave does not repeat between runs
    of one reference (correlation below :data:`REPEAT`), excluded where it does. Nothing named
    and air supported names ``air``: the torque is no function of the state, the inputs or the
    reference."""
    ties = {c: r["added"] for r in rounds for c in r.get("not_told_apart", [])}
    last = rounds[-1]["gains"] if rounds else {}
    for name, rec in records.items():
        if name == HOLD:
            rep = hover["reproduced"].get(HOLD)
            explains = rep is not None and rep >= HOVER_SHARE
            rec["status"] = "explains the hover torque" if explains else "does not explain the hover torque"
            rec["why"] = "" if rep is None else f"reproduces {rep:.0%} of it"
            continue
        if not rec.get("testable"):
            rec["status"], rec["why"] = "untestable", "its columns are zero on these flights (a signal not logged)"
        elif name in named:
            k = named.index(name)
            rec["status"], rec["why"] = "named", f"round {k + 1}: +{rounds[k]['gains'][name]['gain']:.0%} held out"
        elif name in ties:
            rec["status"], rec["why"] = "not told apart", f"its gain lies within {TIE:.0%} of {ties[name]}'s"
        else:
            g = last.get(name, {})
            why = [f"adds {g.get('gain', 0.0):+.0%} held out" + (f" to {', '.join(named)}" if named else "")]
            if not g.get("significant", False):
                why.append("no coefficient's interval excludes zero")
            if g.get("implausible"):
                why.append(f"not physically possible: {g['implausible']}")
            if not g.get("repeats", True):
                why.append(f"what it explains does not repeat between runs of one reference "
                           f"(correlation {repeats['explained'].get(name, 0.0):.2f})")
            rep = hover["reproduced"].get(name)
            if hover["significant"] and rep is not None and rep < HOVER_SHARE:
                why.append(f"reproduces {rep:.0%} of the hover torque")
            rec["status"], rec["why"] = "excluded", "; ".join(why)
    left = repeats["left"].get("named") if named else repeats.get("residual")
    air = {"status": "untestable", "why": "no runs of one reference", "correlation": left}
    if left is not None:
        air = ({"status": "supported", "why": "what is left does not repeat between runs of one reference",
                "correlation": left} if left < REPEAT else
               {"status": "excluded", "why": "what is left repeats between runs of one reference", "correlation": left})
    out_named = list(named) or ([AIR] if air["status"] == "supported" else [])
    return {"hypotheses": records, "rounds": rounds, "named": out_named, "air": air, "hover": hover,
            "repeats": repeats}
