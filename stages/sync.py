"""sync: align the clocks and lags of each flight's streams and resample them to 100 Hz."""

from pathlib import Path

import numpy as np
import pandas as pd
from omegaconf import DictConfig
from tqdm.auto import tqdm

from nanosysid.bags.sync import SyncConfig, motor_lag_estimate, motor_lag_evidence, sync_flight
from nanosysid.dataio import atomic_dir, atomic_file, check_finite, session_of
from nanosysid.errors import DataError
from stages.common import plain, run_stage, write_json


def extracted_flights(folder: Path) -> list[Path]:
    """The flight folders of the extract stage's output."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(f"{folder}: no such folder")
    flights = sorted(p for p in folder.iterdir() if p.is_dir())
    if not flights:
        raise DataError(f"{folder}: no extracted flights")
    return flights


def sync_folder(extract_dir: Path, out_dir: Path, report_dir: Path, cfg: SyncConfig) -> list[dict]:
    """Synchronise every extracted flight; writes ``<flight>.parquet`` and ``sync.json``/``sync.md``.

    The motor telemetry's lag is a property of the rig: it is estimated once per recording
    session (the ``<date>`` of the flights' names) from the sharp thrust transients of all its
    flights, and that one value is applied to each; every flight's own estimate is reported
    beside it.
    """
    flights = extracted_flights(extract_dir)
    tables, evidence = {}, {}
    for d in tqdm(flights, desc="motor lag", unit="flight", disable=None):
        tables[d.name] = {}
        for stream in ("mocap", "odom", "imu", "motors", "setpoint"):
            f = d / f"{stream}.parquet"
            if not f.exists():
                raise DataError(f"{f}: missing (the {stream} stream was not extracted)")
            tables[d.name][stream] = pd.read_parquet(f)
        evidence[d.name] = motor_lag_evidence(str(d), tables[d.name]["imu"], tables[d.name]["motors"], cfg)
    sessions: dict[str, list[str]] = {}
    for name in tables:
        sessions.setdefault(session_of(name), []).append(name)
    lags = {s: motor_lag_estimate([evidence[n] for n in names], cfg) for s, names in sessions.items()}
    reports = []
    with atomic_dir(out_dir, inputs=[extract_dir]) as tmp:
        for d in tqdm(flights, desc="sync", unit="flight", disable=None):
            session = session_of(d.name)
            synced, rep = sync_flight(str(d), tables[d.name], cfg, motor_lag=lags[session])
            rep["flight"] = d.name
            rep["session"] = session
            rep["session_flights"] = len(sessions[session])
            check_finite(synced, f"{d}: synchronised flight")
            synced.to_parquet(tmp / f"{d.name}.parquet", index=False)
            reports.append(rep)
    write_json(Path(report_dir) / "sync.json", reports)
    with atomic_file(Path(report_dir) / "sync.md") as f:
        f.write_text(_sync_markdown(reports))
    return reports


def _ms(v) -> str:
    return "–" if v is None else f"{1000 * v:.1f}"


def _sync_markdown(reports: list[dict]) -> str:
    lines = [
        "# Synchronisation",
        "",
        "Estimated clock relations and lags per flight, and the share of samples each stream",
        "missed (lost packets, dropouts, missed motor readings; filled by the nearest measurement).",
        "",
        "The motor lag applied is the session's: the peak of the cross-covariance of `a_z` with the",
        "sum of squared rotor speeds around the sharp thrust transients of all the session's flights",
        "(in closed loop the rotors answer the thrust disturbances a few tens of milliseconds late, which",
        "pulls a whole-flight correlation towards zero lag). Its 95 % interval is a jackknife over the",
        "flights; each flight's own estimate (over its own transients, interval over them) stands beside it.",
        "",
        "| flight | samples | mocap→STM32 offset [s] | motor lag applied [ms] (95 % interval) | flight's own [ms] (95 % interval, transients) | STM32 drift [ppm] | missing (odom/imu/motors/mocap) | warnings |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in reports:
        m = r["missing"]
        motors = np.mean([m[f"m{i}"] for i in range(1, 5)])
        lo, hi = r["motor_lag_interval"]
        own = r["motor_lag_flight"]
        own_iv = r["motor_lag_flight_interval"] or (None, None)
        lines.append(
            f"| {r['flight']} | {r['samples']} | {r['mocap_to_stm_offset']:.4f} | "
            f"{_ms(r['motor_lag'])} ({_ms(lo)} to {_ms(hi)}) | "
            + (f"{_ms(own)} ({_ms(own_iv[0])} to {_ms(own_iv[1])}, {r['motor_lag_flight_events']}) | " if own is not None
               else "no sharp transient | ")
            + f"{-1e6 * r['stm_drift']:.1f} | {m['odom']:.1%} / {m['imu']:.1%} / {motors:.1%} / {m['mocap']:.1%} | "
            f"{'; '.join(r['warnings']) or '-'} |"
        )
    return "\n".join(lines) + "\n"


def main(cfg: DictConfig) -> None:
    r = cfg.recording
    sync_folder(r.extract_dir, r.sync_dir, r.report_dir, SyncConfig.from_mapping(plain(r.sync)))


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
