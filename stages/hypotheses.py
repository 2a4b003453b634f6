"""hypotheses: the low-frequency roll/pitch torque's hypotheses tested apart on the training
flights (with each flight's take-off hold where the logs hold one). The tests judged on simulated
worlds whose truth is hidden from them are the campaign pipeline's (stages/hypothesis_worlds.py)."""

import logging
from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from nanosysid import hypotheses, protocol
from nanosysid.dynamics import GRAVITY
from nanosysid.dataio import atomic_dir, atomic_file, json_text
from nanosysid.errors import ConfigError
from nanosysid.identify import identified_vehicle
from nanosysid.report.hypotheses import hypotheses_markdown
from stages.common import plain, run_stage, vehicle_of

log = logging.getLogger("nanosysid.hypotheses")


def _holds(cfg: DictConfig, flights, vehicle, window: int, order: int) -> dict:
    """Each training flight's take-off hold offset, from the rig's logs (``rig.paths.raw``)."""
    from nanosysid.rig.holds import take_off_hold
    from nanosysid.rig.logs import LogSpec

    spec = LogSpec.from_mapping(plain(cfg.rig.logs))
    logs = {p.stem: p for p in sorted(Path(cfg.rig.paths.raw).rglob("*.parquet"))}
    by_flight = {name: stem for stem, name in spec.flights.items()}
    out = {}
    for f in flights:
        stem = by_flight.get(f.name)
        if stem is None or stem not in logs:
            continue
        out[f.name] = hypotheses.hold_offset(take_off_hold(logs[stem], spec, f.name), vehicle, window=window,
                                             order=order)
    return out


def main(cfg: DictConfig) -> dict:
    """Write ``<hypotheses.out_dir>/report.md`` and ``result.json``."""
    hc = cfg.hypotheses
    cutoff = float(hc.cutoff)
    window, order = int(cfg.discover.savgol_window), int(cfg.discover.savgol_order)
    bench = protocol.load(cfg.paths.split, horizon=int(cfg.eval.horizon))
    nyquist = 0.5 / float(np.median(np.diff(bench.train[0].t)))
    if cutoff >= nyquist:
        raise ConfigError(f"hypotheses.cutoff: {cutoff:g} Hz; the flights' Nyquist frequency is {nyquist:g} Hz")
    vehicle = identified_vehicle(vehicle_of(cfg), hc.identified)
    data = hypotheses.torque_data(bench.train, vehicle, window=window, order=order, cutoff=cutoff)
    holds = _holds(cfg, bench.train, vehicle, window, order) if bool(hc.holds) else {}
    result = hypotheses.tested_apart(data, hypotheses.reference_correlation(bench.train, data),
                                        vehicle=vehicle, holds=holds or None)
    record = {"named": result["named"], "share": result["share"], "air": result["air"], "hover": result["hover"],
              "repeats": result["repeats"], "hypotheses": result["hypotheses"],
              "rounds": result["rounds"]}
    with atomic_dir(Path(hc.out_dir), inputs=[cfg.paths.split]) as tmp:
        with atomic_file(tmp / "result.json") as f:
            f.write_text(json_text(_without_series(record), sort_keys=True))
        with atomic_file(tmp / "report.md") as f:
            f.write_text(hypotheses_markdown(result, source=str(hc.source), cutoff=cutoff,
                                             weight=vehicle.mass * GRAVITY))
    log.info("hypotheses: named %s (held out %s)", result["named"], result["share"])
    return record


def _without_series(x):
    """``x`` without the flights' sample-by-sample series (json_text turns numpy's types into JSON's)."""
    if isinstance(x, dict):
        return {k: _without_series(v) for k, v in x.items() if k not in ("prediction", "flight_shares")}
    if isinstance(x, (list, tuple)):
        return [_without_series(v) for v in x]
    return x


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
