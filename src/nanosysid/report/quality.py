"""The processed simulated flights against the simulator's truth and its direct output: how
much the recording chain (clocks, lags, losses, filtering) costs, flight by flight and on the
benchmark's scores, with the checks the quality stage fails on."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from nanosysid import protocol, so3
from nanosysid.dataio import SAMPLE_PERIOD, atomic_file, read_flight_csv, write_json
from nanosysid.errors import DataError
from nanosysid.models.physics import PhysicsStep
from nanosysid.rollout import StepPredictor
from nanosysid.vehicle import Vehicle

__all__ = ["quality_report"]


def quality_report(
    flights_dir: Path,
    bags_dir: Path,
    direct_dir: Path,
    sync_report: Path,
    out_dir: Path,
    *,
    vehicle: Vehicle,
    test_trajectories: list[str],
    horizon: int,
    lag_tolerance: float = 0.010,
    rotor_delay: float = 0.0,
) -> dict:
    """Compare the processed flights with the simulator's truth and its direct CSV output.

    Writes ``quality.md`` and ``quality.json`` to ``out_dir``: per flight, the RMS errors of
    position, orientation (geodesic) and rotor speeds against the truth, and the estimated
    lags against the injected ones; and the physics baseline's scores on the processed test
    flights against the same on the direct CSV output. The rotor speeds are compared with the
    truth ``rotor_delay`` s earlier: the delay the data chain leaves in them (``data.rotor_delay``).

    Raises:
        DataError: a flight's applied motor lag misses the injected one, or its own estimate
            misses its session's, by more than ``lag_tolerance`` s (the report is written first).
    """
    syncs = {r["flight"]: r for r in json.loads(Path(sync_report).read_text())}
    rows = []
    processed = {}
    for f in sorted(Path(flights_dir).glob("*.csv")):
        flight = read_flight_csv(f)
        processed[f.stem] = flight
        truth_file = Path(bags_dir) / f"{f.stem}.truth.parquet"
        if not truth_file.exists():
            raise DataError(f"{truth_file}: no truth for flight {f.stem}")
        truth = pd.read_parquet(truth_file)
        injected = json.loads((Path(bags_dir) / f"{f.stem}.truth.json").read_text())
        rep = syncs[f.stem]
        t_stm = rep["t_start_stm"] + flight.t
        idx = np.clip(np.searchsorted(truth["t_stm"].to_numpy(), t_stm - 1e-6), 0, len(truth) - 1)
        tr = truth.iloc[idx]
        if np.abs(tr["t_stm"].to_numpy() - t_stm).max() > 1e-6:
            raise DataError(f"{f}: samples off the STM32 tick lattice of the truth")
        p_err = flight.y[:, :3] - tr[["p0", "p1", "p2"]].to_numpy()
        geo = so3.geodesic_angle(torch.from_numpy(tr[["q0", "q1", "q2", "q3"]].to_numpy().copy()),
                                 torch.from_numpy(np.ascontiguousarray(flight.y[:, 6:10]))).numpy()
        om_true = np.column_stack([np.interp(t_stm - rotor_delay, truth["t_stm"].to_numpy(), truth[f"omega{k}"])
                                   for k in range(4)])
        om_err = flight.u - om_true
        rows.append({
            "flight": f.stem,
            "pos_rms_mm": 1000 * float(np.sqrt((p_err**2).sum(1).mean())),
            "att_rms_rad": float(np.sqrt((geo**2).mean())),
            "rotor_rms_pct_hover": 100 * float(np.sqrt((om_err**2).mean())) / vehicle.hover_speed,
            "mocap_offset_err_ms": 1000 * (rep["mocap_to_stm_offset"] - injected["mocap_to_stm_offset"]),
            "motor_lag_ms": 1000 * rep["motor_lag"],
            "motor_lag_flight_ms": None if rep["motor_lag_flight"] is None else 1000 * rep["motor_lag_flight"],
            "motor_lag_injected_ms": 1000 * injected["motor_lag"],
        })
    if not rows:
        raise DataError(f"{flights_dir}: no processed flights")
    # the nominal model, as the paper defines it (the physics step alone: quality reads no other kind)
    predict = StepPredictor(PhysicsStep(vehicle, dt=SAMPLE_PERIOD), name="physics")
    test_proc = [f for n, f in processed.items() if f.trajectory in test_trajectories]
    test_direct = [read_flight_csv(f) for f in sorted(Path(direct_dir).rglob("*.csv"))]
    test_direct = [f for f in test_direct if f.trajectory in test_trajectories]
    s_proc = protocol.evaluate(predict, test_proc, horizon=horizon)
    s_direct = protocol.evaluate(predict, test_direct, horizon=horizon)
    compare = {}
    for k in ("p", "v", "R", "w"):
        for label, a, b in ((f"h{10}", s_proc.mae[k][9], s_direct.mae[k][9]),
                            (f"h{horizon}", s_proc.mae[k][-1], s_direct.mae[k][-1]),
                            ("simerr", s_proc.simerr[k], s_direct.simerr[k])):
            compare[f"{k}_{label}"] = {"processed": float(a), "direct": float(b), "ratio": float(a / b)}
    tol = 1000 * lag_tolerance
    problems = [f"{r['flight']}: motor lag applied {r['motor_lag_ms']:.1f} ms, injected {r['motor_lag_injected_ms']:.1f} ms"
                for r in rows if abs(r["motor_lag_ms"] - r["motor_lag_injected_ms"]) > tol]
    problems += [f"{r['flight']}: its own motor lag {r['motor_lag_flight_ms']:.1f} ms, its session's {r['motor_lag_ms']:.1f} ms"
                 for r in rows if r["motor_lag_flight_ms"] is not None
                 and abs(r["motor_lag_flight_ms"] - r["motor_lag_ms"]) > tol]
    result = {"flights": rows, "motor_lag_tolerance_ms": tol, "rotor_delay_ms": 1000 * rotor_delay,
              "motor_lag_problems": problems,
              "physics_processed_vs_direct": compare}
    write_json(Path(out_dir) / "quality.json", result)
    with atomic_file(Path(out_dir) / "quality.md") as f:
        f.write_text(_quality_markdown(result, horizon))
    if problems:
        raise DataError(f"{Path(sync_report)}: the motor telemetry's lag is off by more than {tol:g} ms "
                        f"(preprocess.sync.lag_tolerance) in {len(problems)} flight(s): " + "; ".join(problems))
    return result


def _quality_markdown(q: dict, horizon: int) -> str:
    lines = [
        "# Processed data against the simulator's truth",
        "",
        "Each processed flight (bags -> extract -> sync -> filter) against the noise-free truth at the",
        "same STM32 ticks. Targets: position RMS ≤ 5 mm, orientation (geodesic) RMS ≤ 0.01 rad, rotor",
        f"speed RMS ≤ 2 % of hover (against the truth {q['rotor_delay_ms']:g} ms earlier: the delay the data chain leaves "
        "in them, `data.rotor_delay`);",
        f"lags within {q['motor_lag_tolerance_ms']:g} ms of the injected ones. The motor lag",
        "applied is the session's (the setpoints as instruments over all its flights, `reports/data/sync.md`);",
        "a flight's own estimate, where it has sharp transients, must agree with it too: the stage fails",
        "otherwise.",
        "",
        "| flight | position RMS [mm] | orientation RMS [rad] | rotor RMS [% hover] | mocap offset error [ms] | motor lag applied / flight's own / injected [ms] |",
        "|---|---|---|---|---|---|",
    ]
    for r in q["flights"]:
        own = "–" if r["motor_lag_flight_ms"] is None else f"{r['motor_lag_flight_ms']:.1f}"
        lines.append(
            f"| {r['flight']} | {r['pos_rms_mm']:.2f} | {r['att_rms_rad']:.4f} | {r['rotor_rms_pct_hover']:.2f} | "
            f"{r['mocap_offset_err_ms']:+.2f} | {r['motor_lag_ms']:.1f} / {own} / {r['motor_lag_injected_ms']:.1f} |"
        )
    for p in q["motor_lag_problems"]:
        lines.append(f"\n**Lag check failed**: {p}")
    lines += [
        "",
        "## The physics baseline on processed data against the simulator's direct output",
        "",
        "Test flights. The pipeline must not destroy the signal: the ratios stay within 1 ± 0.25.",
        "",
        "| quantity | processed | direct | ratio |",
        "|---|---|---|---|",
    ]
    for k, v in q["physics_processed_vs_direct"].items():
        lines.append(f"| {k} | {v['processed']:.4f} | {v['direct']:.4f} | {v['ratio']:.2f} |")
    return "\n".join(lines) + "\n"
