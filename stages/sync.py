"""sync: align the clocks and lags of each flight's streams and resample them to 100 Hz."""

from pathlib import Path

import numpy as np
import pandas as pd
from omegaconf import DictConfig
from tqdm.auto import tqdm

from nanosysid.bags.sync import SyncConfig, sync_flight
from nanosysid.dataio import atomic_dir, atomic_file
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
    """Synchronise every extracted flight; writes ``<flight>.parquet`` and ``sync.json``/``sync.md``."""
    reports = []
    with atomic_dir(out_dir, inputs=[extract_dir]) as tmp:
        for d in tqdm(extracted_flights(extract_dir), desc="sync", unit="flight", disable=None):
            tables = {}
            for stream in ("mocap", "odom", "imu", "motors", "setpoint"):
                f = d / f"{stream}.parquet"
                if not f.exists():
                    raise DataError(f"{f}: missing (the {stream} stream was not extracted)")
                tables[stream] = pd.read_parquet(f)
            synced, rep = sync_flight(str(d), tables, cfg)
            rep["flight"] = d.name
            synced.to_parquet(tmp / f"{d.name}.parquet", index=False)
            reports.append(rep)
    write_json(Path(report_dir) / "sync.json", reports)
    with atomic_file(Path(report_dir) / "sync.md") as f:
        f.write_text(_sync_markdown(reports))
    return reports


def _sync_markdown(reports: list[dict]) -> str:
    lines = [
        "# Synchronisation",
        "",
        "Estimated clock relations and lags per flight, and the share of samples each stream",
        "missed (lost packets, dropouts, missed motor readings; filled by the nearest measurement).",
        "",
        "| flight | samples | mocap→STM32 offset [s] | motor lag [ms] | STM32 drift [ppm] | missing (odom/imu/motors/mocap) | warnings |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in reports:
        m = r["missing"]
        motors = np.mean([m[f"m{i}"] for i in range(1, 5)])
        lines.append(
            f"| {r['flight']} | {r['samples']} | {r['mocap_to_stm_offset']:.4f} | {1000 * r['motor_lag']:.1f} | "
            f"{-1e6 * r['stm_drift']:.1f} | {m['odom']:.1%} / {m['imu']:.1%} / {motors:.1%} / {m['mocap']:.1%} | "
            f"{'; '.join(r['warnings']) or '-'} |"
        )
    return "\n".join(lines) + "\n"


def main(cfg: DictConfig) -> None:
    r = cfg.recording
    sync_folder(r.extract_dir, r.sync_dir, r.report_dir, SyncConfig.from_mapping(plain(r.sync)))


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
