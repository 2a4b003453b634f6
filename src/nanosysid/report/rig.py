"""The benchmark on the rig's real flights beside the paper: every model's row beside the paper's
table with the relative difference of each SimErr cell, the identified coefficients beside the
paper's, and the motor alignment beside the authors' own.

Real flights have no truth: an estimate is judged by its interval from independent repeats, by
its agreement across flights and with the paper, and by what the simulated worlds showed the
estimator can do.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd

from nanosysid.metrics import QUANTITIES
from nanosysid.protocol import Scores
from nanosysid.report.paper import PAPER_IDENTIFIED, PAPER_RESULTS

__all__ = ["results_beside_paper", "results_section", "authors_alignment", "alignment_section",
           "identification_section", "WORSE"]

_LABEL = {"p": "p [m]", "v": "v [m/s]", "R": "R [rad]", "w": "ω [rad/s]"}
_HORIZONS = (1, 10, 50)
WORSE = 0.25  # a row more than this much worse than the paper's in a SimErr cell has its cause stated


def results_beside_paper(scores: Mapping[str, Scores], *, worse: float = WORSE) -> dict[str, Any]:
    """Each model's MAE at h = 1, 10, 50 and SimErr beside the paper's, and the relative difference
    of each SimErr cell; ``worse`` lists the models with a cell more than ``worse`` above the paper's."""
    rows: dict[str, Any] = {}
    for m, s in scores.items():
        paper = PAPER_RESULTS.get(m)
        row = {}
        for k in QUANTITIES:
            ours = [float(s.mae[k][h - 1]) for h in _HORIZONS if h <= len(s.mae[k])] + [float(s.simerr[k])]
            row[k] = {"ours": ours, "paper": list(paper[k]) if paper else None,
                      "simerr_difference": (ours[-1] / paper[k][3] - 1) if paper else None}
        rows[m] = row
    flagged = [m for m, r in rows.items() if any(r[k]["simerr_difference"] is not None
                                                  and r[k]["simerr_difference"] > worse for k in QUANTITIES)]
    return {"rows": rows, "worse": flagged, "threshold": worse}


def results_section(res: Mapping[str, Any], causes: Mapping[str, str] | None = None) -> str:
    """Markdown: the table with the paper's row under each of ours, and the causes of the rows
    more than the threshold worse than the paper's."""
    L = ["## The results beside the paper's table", "",
         "MAE on the test flights (Melon 1, 4, 5) at h = 1, 10, 50 and SimErr (the sum over h = 1..50), per quantity; "
         "under each of our rows the paper's (its table of numerical performance) and the relative difference of "
         "each SimErr cell. Naive and physics learn nothing, so theirs check the data path and the protocol.", "",
         "| model | " + " | ".join(f"{_LABEL[k]} h=1 | h=10 | h=50 | SimErr" for k in QUANTITIES) + " |",
         "|---|" + "---|" * (4 * len(QUANTITIES))]
    for m, r in res["rows"].items():
        L.append(f"| {m} | " + " | ".join(" | ".join(f"{v:.4f}" for v in r[k]["ours"][:-1]) + f" | *{r[k]['ours'][-1]:.4g}*"
                                           for k in QUANTITIES) + " |")
        if r[QUANTITIES[0]]["paper"] is not None:
            L.append(f"| paper | " + " | ".join(" | ".join(f"{v:.4f}" for v in r[k]["paper"][:-1])
                                                + f" | *{r[k]['paper'][-1]:.4g}* ({r[k]['simerr_difference']:+.1%})"
                                                for k in QUANTITIES) + " |")
    L.append("")
    flagged = res["worse"]
    if flagged:
        L += [f"Rows with a SimErr cell more than {res['threshold']:.0%} worse than the paper's: "
              f"{', '.join(flagged)}.", ""]
        for m in flagged:
            L.append(f"- **{m}**: {(causes or {}).get(m, 'cause not measured')}")
        L.append("")
    else:
        L += [f"No row has a SimErr cell more than {res['threshold']:.0%} worse than the paper's.", ""]
    return "\n".join(L)


def _best_shift(processed: np.ndarray, raw: np.ndarray, rows: np.ndarray, reach: int) -> int:
    """The shift k for which ``processed[i]`` is closest to ``raw[rows[i] + k]`` (RMS)."""
    errs = {k: float(np.sqrt(np.nanmean((processed - raw[rows + k]) ** 2))) for k in range(-reach, reach + 1)
            if rows.min() + k >= 0 and rows.max() + k < len(raw)}
    return min(errs, key=errs.get)


def authors_alignment(log: pd.DataFrame, processed: pd.DataFrame, *, rads_per_erpm: float, dt: float = 0.01,
                      reach: int = 8) -> dict[str, Any]:
    """The motor alignment the authors applied to one flight, as a lag in the sync's convention
    (the motor stamps moved by ``-lag``), read two ways: their ``lag_samples`` field, and measured,
    the shift of their rotor speeds against the log's eRPM less the shift of their gyro against
    the log's (the index their rows carry may be off by one; the difference is the alignment).
    Rotor speeds are compared as ``eRPM * rads_per_erpm`` (the rig's conversion,
    :attr:`nanosysid.rig.logs.LogSpec.rads_per_erpm`); both shifts are whole samples."""
    rows = processed["Unnamed: 0"].to_numpy()
    erpm = log[["m1_erpm", "m2_erpm", "m3_erpm", "m4_erpm"]].interpolate(limit_direction="both").to_numpy()
    k_motor = _best_shift(processed[["m1_rads", "m2_rads", "m3_rads", "m4_rads"]].to_numpy(),
                          erpm * rads_per_erpm, rows, reach)
    k_state = _best_shift(processed[["wx", "wy", "wz"]].to_numpy(),
                          log[["wx", "wy", "wz"]].interpolate(limit_direction="both").to_numpy(), rows, reach)
    # their motor sample of log row j + (k_motor - k_state) stands at row j: moved by that many samples
    return {"lag_samples_field": int(processed["lag_samples"].iloc[0]),
            "motor_shift": k_motor, "state_shift": k_state, "lag": (k_motor - k_state) * dt, "resolution": dt}


def alignment_section(sync: Sequence[Mapping[str, Any]], authors: Mapping[str, Mapping[str, Any]]) -> tuple[str, dict]:
    """Markdown and record: the rig-level motor lag with its interval, every flight's own, and the
    authors' per-flight alignment beside it; a flight's alignment is contradicted when its own 95 %
    interval misses the authors' value widened by half their grid step (they shift by whole samples)."""
    first = sync[0]
    lo, hi = first["motor_lag_interval"]
    rec: dict[str, Any] = {"rig": {"lag": first["motor_lag"], "ci95": [lo, hi], "method": first["motor_lag_method"]},
                           "flights": {}}
    ms = lambda v: "–" if v is None else f"{1e3 * v:.1f}"  # noqa: E731
    L = ["## The motor alignment beside the authors'", "",
         f"The rig-level motor lag (the sync stage's, by {first['motor_lag_method']}; one value for the session's "
         f"{len(sync)} flights): **{ms(first['motor_lag'])} ms**, 95 % interval {ms(lo)} to {ms(hi)} ms "
         "(a jackknife over blocks). A negative lag moves the motor stamps later: in these logs the rotor speeds "
         "stand a little ahead of the acceleration they cause. Each flight's own estimate (around its sharp thrust "
         "transients) beside it, and the authors' alignment where they published one: their `lag_samples`, and the "
         "shift their processed rotor speeds show against the raw eRPM relative to their gyro's (both in whole "
         "samples).", "",
         "| flight | own lag [ms] | own 95 % interval [ms] | transients | authors' lag [ms] (their lag_samples) | the data |",
         "|---|---|---|---|---|---|"]
    for r in sync:
        own, iv = r.get("motor_lag_flight"), r.get("motor_lag_flight_interval") or [None, None]
        a = authors.get(r["flight"])
        contradicts = (a is not None and iv[0] is not None
                       and (iv[1] < a["lag"] - a["resolution"] / 2 or iv[0] > a["lag"] + a["resolution"] / 2))
        rig_off = own is not None and iv[0] is not None and (iv[1] < lo or iv[0] > hi)
        words = []
        if a is not None:
            words.append("no interval" if iv[0] is None else "contradict the authors' value" if contradicts
                         else "agree with the authors' value (to their one-sample step)")
        if rig_off:
            words.append("own lag outside the rig-level interval")
        verdict = "; ".join(words) or "–"
        rec["flights"][r["flight"]] = {"own": own, "ci95": iv, "transients": r.get("motor_lag_flight_events"),
                                       "authors": a, "verdict": verdict, "contradicts_authors": contradicts,
                                       "outside_rig_interval": rig_off}
        L.append(f"| {r['flight']} | {ms(own)} | {ms(iv[0])} to {ms(iv[1])} | {r.get('motor_lag_flight_events', 0)} | "
                 + (f"{ms(a['lag'])} ({a['lag_samples_field']})" if a else "–") + f" | {verdict} |")
    L.append("")
    contradicted = [f for f, v in rec["flights"].items() if v["contradicts_authors"]]
    apart = [f for f, v in rec["flights"].items() if v["outside_rig_interval"]]
    L.append((f"The data contradict the authors' alignment of {', '.join(contradicted)}. " if contradicted else
              "The data contradict none of the authors' alignments (to their one-sample step). ")
             + (f"The flights whose own lag lies outside the rig-level interval ({', '.join(apart)}) carry a motor "
                "timing of their own in these logs" + "".join(
                    f"; the authors aligned {f} by {authors[f]['lag_samples_field']} samples themselves"
                    for f in apart if f in authors and authors[f]["lag_samples_field"])
                + ": one lag for the whole rig does not hold for them." if apart else ""))
    L.append("")
    rec["contradicted"], rec["outside_rig_interval"] = contradicted, apart
    return "\n".join(L), rec


def identification_section(params: Mapping[str, Any], yaw_reference: Mapping[str, float],
                           yaw_measured: Mapping[str, float], sim: Mapping[str, Any] | None = None) -> tuple[str, dict]:
    """Markdown and record: k_F and k_M with their intervals beside the paper's, and what the
    flights support for k_M (the yaw reference's range on each flight against the yaw's); ``sim``,
    the simulated world's identification (``reports/sim/stats.json``), says what the estimator
    gave there against nature's truth."""
    f, m = params["thrust_fit"], params["yaw_fit"]
    ci = lambda fit: "–" if fit.get("ci95") is None else f"{fit['ci95'][0]:.4g} to {fit['ci95'][1]:.4g}"  # noqa: E731
    rec = {"k_f": {"estimate": params["k_f"], "ci95": f.get("ci95"), "paper": PAPER_IDENTIFIED["k_f"],
                   "difference": params["k_f"] / PAPER_IDENTIFIED["k_f"] - 1, "estimator": f["estimator"]},
           "k_m": {"estimate": params["k_m"], "ci95": m.get("ci95"), "ci95_inertia": m.get("ci95_inertia"),
                   "paper": PAPER_IDENTIFIED["k_m"], "difference": params["k_m"] / PAPER_IDENTIFIED["k_m"] - 1,
                   "estimator": m["estimator"]},
           "yaw_reference_range": dict(yaw_reference), "yaw_range": dict(yaw_measured)}
    ref_max = max(yaw_reference.values()) if yaw_reference else 0.0
    L = ["## Identification beside the paper's", "",
         f"On the {len(params.get('train_flights', []))} training flights, with intervals from the flights as "
         "independent repeats (a delete-one-flight jackknife).", "",
         "| coefficient | estimator | estimate | 95 % interval | paper | difference |", "|---|---|---|---|---|---|",
         f"| k_F [N s²/rad²] | {f['estimator']} | {params['k_f']:.4g} | {ci(f)} | {PAPER_IDENTIFIED['k_f']:.4g} | "
         f"{rec['k_f']['difference']:+.1%} |",
         f"| k_M [N m s²/rad²] | {m['estimator']} | {params['k_m']:.4g} | {ci(m)} | {PAPER_IDENTIFIED['k_m']:.4g} | "
         f"{rec['k_m']['difference']:+.1%} |", ""]
    if m.get("ci95_inertia"):
        lo, hi = m["ci95_inertia"]
        L += [f"With the yaw inertia anywhere in {m['inertia_z_range'][0]:.4g} to {m['inertia_z_range'][1]:.4g} kg m² "
              f"(the flights identify k_M / J_z), k_M's 95 % interval is {lo:.4g} to {hi:.4g}.", ""]
    L += ["What the flights support for k_M: the campaign flew no yaw calibration flight, and the reference does not "
          f"excite yaw (its yaw setpoint spans at most {ref_max:.3f} rad on any flight, while the measured yaw spans "
          f"{min(yaw_measured.values()):.2f} to {max(yaw_measured.values()):.2f} rad, moved by the disturbances the "
          "yaw loop answers). With no instrument, k_M is the paper's least squares on closed-loop flights, which the "
          "yaw loop biases towards zero: its answers to the yaw disturbances correlate the rotor-speed difference "
          "with the residual."
          + (f" On the simulated world that estimator gives {sim['paper_method']:.3g} where nature's k_M is "
             f"{sim['nature']:.3g} ({sim['paper_method'] / sim['nature'] - 1:+.0%}; reports/sim/stats.md): read this "
             "k_M as the paper's method reproduced, not as the rotors' yaw coefficient." if sim else ""), ""]
    rec["sim"] = dict(sim) if sim else None
    return "\n".join(L), rec


def yaw_reference_ranges(extract_dir: Path) -> dict[str, float]:
    """Each flight's range (rad) of the yaw setpoint while the reference is set (the extract
    stage's setpoint streams)."""
    out = {}
    for d in sorted(p for p in Path(extract_dir).iterdir() if p.is_dir()):
        sp = pd.read_parquet(d / "setpoint.parquet")
        on = np.abs(sp[["x", "y", "z"]].to_numpy()).sum(axis=1) > 0
        yaw = np.unwrap(sp["yaw"].to_numpy()[on])
        out[d.name] = float(yaw.max() - yaw.min()) if yaw.size else 0.0
    return out


def yaw_range(flight) -> float:
    """The range (rad) of a flight's measured yaw (from its attitude quaternions, unwrapped)."""
    qx, qy, qz, qw = flight.y[:, 6:10].T
    yaw = np.unwrap(np.arctan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz)))
    return float(yaw.max() - yaw.min())


def measured_causes(results: Mapping[str, Any], scores: Mapping[str, Scores]) -> dict[str, str]:
    """For each row worse than the paper's by over the threshold, what the scores show of where the
    excess lies: its SimErr over physics' beside the paper's ratio (a ratio as the paper's puts the
    excess in what every model shares: the flights, the data path), and its test flights apart
    (an excess on one flight is that flight's, not the model's)."""
    causes = {}
    for m in results["worse"]:
        rows = results["rows"][m]
        bad = [k for k in QUANTITIES if rows[k]["simerr_difference"] is not None
               and rows[k]["simerr_difference"] > results["threshold"]]
        parts = []
        for k in bad:
            text = f"{_LABEL[k].split()[0]}: SimErr {rows[k]['ours'][-1]:.4g} against the paper's {rows[k]['paper'][-1]:.4g}"
            if "physics" in scores and m != "physics":
                ours = scores[m].simerr[k] / scores["physics"].simerr[k]
                theirs = rows[k]["paper"][-1] / PAPER_RESULTS["physics"][k][3]
                text += (f"; over physics' {ours:.2f} here, {theirs:.2f} in the paper, so the excess is the "
                         + ("model's own (physics matches the paper's)" if ours > theirs * (1 + results["threshold"])
                            else "flights' and the data path's, shared with physics"))
            flights = scores[m].per_flight
            if flights:
                per = {f: s.simerr[k] for f, s in flights.items()}
                text += "; per test flight " + ", ".join(f"{f.split('_')[-1]} {v:.4g}" for f, v in per.items())
            parts.append(text)
        causes[m] = ". ".join(parts)
    return causes


def accel_against_authors(imu: pd.DataFrame, log: pd.DataFrame, processed: pd.DataFrame) -> dict[str, float]:
    """RMS (m/s²) of the body-frame specific force the reader made (``imu``, the extract stage's
    stream) and of the logged ``ax ay az`` as they stand, each against the authors' processed
    ``ax_body ay_body az_body`` at the same log rows (theirs are smoothed: a few tenths remain)."""
    t = log["t"].to_numpy()[processed["Unnamed: 0"].to_numpy()]
    ours = imu.set_index("t_src")[["ax", "ay", "az"]]
    both = np.isin(t, ours.index)
    theirs = processed[["ax_body", "ay_body", "az_body"]].to_numpy()[both]
    logged = log.set_index("t").loc[t[both], ["ax", "ay", "az"]].to_numpy()
    rms = lambda a: float(np.sqrt(np.mean((a - theirs) ** 2)))  # noqa: E731
    return {"ours": rms(ours.loc[t[both]].to_numpy()), "logged": rms(logged), "rows": int(both.sum())}


def quality_section(logs: Mapping[str, Any], sync: Sequence[Mapping[str, Any]], filtered: Sequence[Mapping[str, Any]],
                    accel: Mapping[str, Mapping[str, float]]) -> str:
    """Markdown: the rules the reader applied to each log, the share of held samples the sync
    found per stream, the gaps the filter left, and the acceleration frame checked against the
    authors' processed values."""
    by_sync = {r["flight"]: r for r in sync}
    by_filter = {r["flight"]: r for r in filtered}
    L = ["# The rig's flights: what the logs held and what was done with it", "",
         "Each log read by the product's rules (`nanosysid.rig.logs`): `segment` cuts the flight from the reference's "
         "phases and the `is_flying` flag; `incomplete` leaves out a log that ends before its reference lands; "
         "`missed` turns a NaN reading into a missed message; `spike` does so for an eRPM above "
         "`rig.logs.max_erpm`; `alias` reads a column spelt otherwise; `yaw_torque_copy` leaves out a logged yaw "
         "torque that repeats the thrust command. The held share is the grid rows where a stream had no new message "
         "(the merge held the last one): the sync marks them missing and the filter interpolates gaps up to "
         "`preprocess.filter.max_gap` samples.", "",
         "| flight (log) | kept | segment [s] | motor NaN (m1-m4) | eRPM spikes (largest) | held: odom / motors / mocap | other rules | filter gaps left |",
         "|---|---|---|---|---|---|---|---|"]
    for name, f in logs["flights"].items():
        r = f["rules"]
        s = r["segment"]
        spikes = r["spike"]["count"]
        others = [k for k in ("alias", "yaw_torque_copy") if k in r] + [f"missed {k} {v}" for k, v in r["missed"].items()]
        gaps = by_filter.get(name, {}).get("gaps_left", {})
        L.append(f"| {name} ({f['log']}) | {'yes' if f['kept'] else 'no: incomplete'} | {s['start']:.2f}-{s['stop']:.2f} "
                 f"({s['samples'] / 100:.2f} s{'' if s['complete'] else ', no landing'}) | "
                 f"{' / '.join(str(v) for v in r['missed_motor_readings'].values())} | "
                 f"{sum(spikes.values())}" + (f" ({r['spike']['largest_erpm']:.0f})" if sum(spikes.values()) else "")
                 + f" | {r['held']['odom']:.0%} / {r['held']['motors']:.0%} / {r['held']['mocap']:.0%} | "
                 f"{', '.join(others) or '-'} | {', '.join(f'{k}: {len(v)}' for k, v in gaps.items()) or '-'} |")
    L.append("")
    shares = {n: f["rules"]["accel_frame"]["lateral_share"] for n, f in logs["flights"].items()}
    frame = next(iter(logs["flights"].values()))["rules"]["accel_frame"]["configured"]
    other = "body" if frame == "world" else "world"
    span = lambda f: f"{min(s[f] for s in shares.values()):.0%} to {max(s[f] for s in shares.values()):.0%}"  # noqa: E731
    L += ["## The acceleration's frame", "",
          f"The logs' `ax ay az` are the specific force in the {frame} frame (`rig.logs.accel_frame`), as the data "
          "say: a quadrotor's specific force lies along its thrust axis, and the part across that axis is "
          f"{span(frame)} of its size read in the {frame} frame (drag and the rotors' tilt), {span(other)} read in "
          f"the {other} frame. Against the authors' processed `ax_body ay_body az_body` (RMS over their rows, "
          "m/s²):", "",
          "| flight | rows | ours (rotated to the body) | the logged values as they stand |", "|---|---|---|---|"]
    for name, a in accel.items():
        L.append(f"| {name} | {a['rows']} | {a['ours']:.3f} | {a['logged']:.3f} |")
    L.append("")
    return "\n".join(L)
