"""compare: the dataset and the benchmark's results against the paper's real flights
(trajectory statistics, the naive and physics rows, the pattern of the results), and the
simulated world's effects."""

import json
import logging
from pathlib import Path

import pandas as pd

from omegaconf import DictConfig

from nanosysid import identify, protocol
from nanosysid.dataio import atomic_file, json_text
from nanosysid.identify import identified_vehicle
from nanosysid.report import paper, realism, rig, tables
from nanosysid.report.stats import stats_markdown, trajectory_stats
from nanosysid.rig.logs import LogSpec
from nanosysid.report.world import nature_thrust_coefficient, world_markdown
from nanosysid.sim.world import ROTOR_DRAG, ROTOR_HUB_HEIGHT, ROTOR_INERTIA
from stages.common import plain, run_stage, vehicle_of

log = logging.getLogger("nanosysid.compare")


def main(cfg: DictConfig) -> None:
    """``<paths.sim_report>/stats.md`` (and ``stats.json``: the figures and each criterion's verdict);
    on the rig's real flights ``<rig.paths.report>/paper.md`` and ``paper.json``, and the default world
    beside them, ``world.md`` and ``world.json``."""
    if str(cfg.data.source) == "rig":
        return rig_main(cfg)
    names = [m for m in paper.PAPER_MODELS if m in cfg.models]
    scores = tables.load_scores(cfg.paths.eval, names)
    bench = protocol.load(cfg.paths.split, horizon=int(cfg.eval.horizon))
    comparison = paper.compare_results(scores)
    source = str(cfg.data.source)
    parts = ["# The dataset against the paper's real flights", "",
             f"Data: `{source}` flights ({len(bench.train)} for training, {len(bench.test)} for testing); every model "
             "scored on the test flights by the evaluate stage.", ""]
    if source.startswith("sim"):
        parts.append(world_markdown(plain(cfg.sim.effects)))
    parts.append(stats_markdown(trajectory_stats(bench.train + bench.test)).replace("# ", "## ", 1))
    if source.startswith("sim"):
        params = identify.read_identified(Path(cfg.identify.out_dir) / "params.json")
        vehicle = vehicle_of(cfg)
        paper.compare_identification(comparison, params, k_f=vehicle.k_f, k_m=vehicle.k_m,
                                     k_f_thrust=nature_thrust_coefficient(Path(cfg.sim.out_dir) / "csv",
                                                                         params["train_flights"]))
        parts.append(paper.identification_markdown(comparison))
    parts.append(paper.results_markdown(comparison))
    out = Path(cfg.paths.sim_report)
    with atomic_file(out / "stats.md") as tmp:
        tmp.write_text("\n".join(parts))
    with atomic_file(out / "stats.json") as tmp:
        tmp.write_text(json_text(comparison.to_dict()))
    log.info("compare: %s", ", ".join(f"{k}: {'yes' if v else 'no'}" for k, v in comparison.checks.items()))


def rig_main(cfg: DictConfig) -> None:
    """Every model beside the paper's table, the identification beside the paper's and the motor
    alignment beside the authors', on the rig's real flights."""
    names = list(cfg.models)
    scores = tables.load_scores(cfg.paths.eval, names)
    bench = protocol.load(cfg.paths.split, horizon=int(cfg.eval.horizon))
    results = rig.results_beside_paper(scores)
    comparison = paper.compare_results({m: s for m, s in scores.items() if m in paper.PAPER_MODELS})
    sim_stats = json.loads((Path(cfg.paths.sim_report) / "stats.json").read_text())
    paper.compare_world(comparison, {(r["model"], r["quantity"]): r["ours"] for r in sim_stats.get("ratios", [])})
    causes = rig.measured_causes(results, scores)
    sync = json.loads((Path(cfg.preprocess.report_dir) / "sync.json").read_text())
    logs_dir, flights = Path(cfg.rig.paths.raw), plain(cfg.rig.logs.flights)
    spec = LogSpec.from_mapping(plain(cfg.rig.logs))
    authors = {}
    for f in sorted((logs_dir / "processed").glob("*.csv")):
        if f.stem in flights:
            authors[flights[f.stem]] = rig.authors_alignment(pd.read_parquet(logs_dir / "raw" / f"{f.stem}.parquet"),
                                                             pd.read_csv(f), rads_per_erpm=spec.rads_per_erpm)
    alignment, lag_rec = rig.alignment_section(sync, authors)
    yaw_ref = rig.yaw_reference_ranges(Path(cfg.preprocess.extract_dir))
    yaw = {f.name: rig.yaw_range(f) for f in bench.train + bench.test}
    sim_ident = sim_stats.get("identification", {}).get("k_m")
    ident, ident_rec = rig.identification_section(
        identify.read_identified(Path(cfg.identify.out_dir) / "params.json"), yaw_ref, yaw,
        {"paper_method": sim_ident["paper_method"], "nature": sim_ident["nature"]} if sim_ident else None)
    parts = ["# The benchmark on the rig's real flights, beside the paper", "",
             f"The paper's 2025-10-17 campaign ({len(bench.train)} training flights, {len(bench.test)} test flights: "
             f"{', '.join(f.name for f in bench.test)}), read from the authors' logs and processed by this product's "
             "own sync, filter and split; every model trained and scored here.", "",
             rig.results_section(results, causes), ident, alignment,
             stats_markdown(trajectory_stats(bench.train + bench.test), what="the rig's").replace("# ", "## ", 1),
             paper.results_markdown(comparison)]
    out = Path(cfg.rig.paths.report)
    world = _world_beside(cfg, bench, sync)
    with atomic_file(out / "world.md") as tmp:
        tmp.write_text(realism.markdown(world))
    with atomic_file(out / "world.json") as tmp:
        tmp.write_text(json_text(world))
    with atomic_file(out / "paper.md") as tmp:
        tmp.write_text("\n".join(parts))
    with atomic_file(out / "paper.json") as tmp:
        tmp.write_text(json_text({"results": results, "causes": causes, "identification": ident_rec,
                                  "motor_lag": lag_rec, "pattern": comparison.to_dict()}))
    log.info("compare: %d models on the rig's flights; worse than the paper by over %.0f%%: %s", len(names),
             100 * rig.WORSE, ", ".join(results["worse"]) or "none")


def _world_beside(cfg: DictConfig, bench, sync) -> dict:
    """The default world's flights (the simulated pipeline's split, its identified k_F and k_M,
    its motor lag) beside the rig's (:mod:`nanosysid.report.realism`)."""
    p = cfg.rig.paths
    sim_bench = protocol.load(p.world_split, horizon=int(cfg.eval.horizon))
    w, o = int(cfg.identify.savgol_window), int(cfg.identify.savgol_order)
    sim_vehicle = identified_vehicle(vehicle_of(cfg), str(Path(p.world_identify) / "params.json"))
    rig_vehicle = identified_vehicle(vehicle_of(cfg), str(Path(cfg.identify.out_dir) / "params.json"))
    sim_sync = json.loads((Path(p.world_data_report) / "sync.json").read_text())
    world = realism.analyses(sim_bench.train + sim_bench.test, sim_vehicle, w, o)
    real = realism.analyses(bench.train + bench.test, rig_vehicle, w, o)
    result = realism.compare(world.pop("figures"), real.pop("figures"),
                             (float(sim_sync[0]["motor_lag"]), float(sync[0]["motor_lag"])))
    return {**result, **{k: {"world": world[k], "real": real[k]} for k in world},
            "rotor_drag_z": ROTOR_DRAG[2] * float(cfg.sim.effects.get("rotor_drag", 0.0)),
            "hub_moment": ROTOR_DRAG[0] * ROTOR_HUB_HEIGHT * float(cfg.sim.effects.get("rotor_drag", 0.0)),
            "rotor_inertia": ROTOR_INERTIA * float(cfg.sim.effects.get("rotor_inertia", 0.0))}


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
