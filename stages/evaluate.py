"""evaluate: score one model on the test flights with the multi-horizon protocol."""

import json
import logging
from pathlib import Path
from typing import Any

from omegaconf import DictConfig

from nanosysid import protocol
from nanosysid.dataio import atomic_dir
from nanosysid.predictors import build_from_options, step_cost
from nanosysid.report.tables import results_table_md
from stages.common import model_options, run_stage

log = logging.getLogger("nanosysid.evaluate")


def metrics_payload(scores: protocol.Scores, table_horizons: list[int], cost: dict[str, Any]) -> dict[str, Any]:
    """The content of ``metrics.json``, the headline figures DVC shows and compares: SimErr,
    the MAE at the table's horizons, and the model's cost per step."""
    return {"simerr": scores.simerr, **{f"h{h}": scores.at(h) for h in table_horizons},
            "cost": {k: v for k, v in cost.items() if k in ("params", "flops")}}


def main(cfg: DictConfig, name: str) -> protocol.Scores:
    """Score ``cfg.models[name]`` on the test flights of ``cfg.paths.split``.

    Writes to ``<paths.eval>/<name>/``: ``scores.json`` (MAE curves, per flight),
    ``metrics.json`` (headline figures), ``table.md`` and ``rollouts/`` (the rollouts the report's
    figures and the recordings show, :func:`nanosysid.protocol.save_kept`).
    """
    options = model_options(cfg, name)
    horizon = int(cfg.eval.horizon)
    bench = protocol.load(cfg.paths.split, horizon=horizon)
    predict = build_from_options(options)
    scores, kept = protocol.evaluate(predict, bench.test, horizon=horizon, batch_size=int(cfg.eval.batch_size),
                                     keep=int(cfg.visualize.stride))
    out = Path(cfg.paths.eval) / name
    # table horizons beyond a shortened evaluation horizon have no value to show
    table_h = [h for h in cfg.eval.table_horizons if h <= horizon]
    full = {"model": name, **scores.to_dict()}
    cost = step_cost(options["kind"], predict)
    with atomic_dir(out, inputs=[cfg.paths.split]) as tmp:  # the files replaced as a set
        (tmp / "scores.json").write_text(json.dumps(full, indent=1, allow_nan=False) + "\n")
        (tmp / "metrics.json").write_text(json.dumps(metrics_payload(scores, table_h, cost), indent=1,
                                                     allow_nan=False) + "\n")
        (tmp / "table.md").write_text(results_table_md({name: scores}, table_h))
        (tmp / "rollouts").mkdir()
        protocol.save_kept(kept, tmp / "rollouts")
    log.info("evaluate %s: %d windows, SimErr %s", name, scores.n_windows,
             ", ".join(f"{k} {v:.4g}" for k, v in scores.simerr.items()))
    return scores


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__, name_arg="model"))
