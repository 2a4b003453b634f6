"""The train stage's work: one learned model from its config block."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from nanosysid import benchmark
from nanosysid.config import ConfigError
from nanosysid.models import identified_vehicle
from nanosysid.models.training import train_model

__all__ = ["train_from_config", "hparams_from_config"]


def hparams_from_config(m: dict[str, Any]) -> dict[str, Any]:
    """The architecture block a checkpoint stores, from a ``models.<name>`` config block."""
    if m["arch"] == "lstm":
        return {"arch": "lstm", "lstm_hidden": int(m["hidden"]), "init_hidden": int(m["init_hidden"])}
    hp: dict[str, Any] = {"arch": m["arch"], "hidden": [int(h) for h in m["hidden"]]}
    if m["arch"] == "phys_res":
        v = identified_vehicle(m["vehicle"], m.get("identified"))
        hp.update(vehicle={k: (list(x) if isinstance(x, tuple) else x) for k, x in v.dynamics_kwargs().items()},
                  dt=float(m["dt"]), substeps=int(m["substeps"]))
    return hp


def train_from_config(cfg: DictConfig, name: str) -> dict[str, Any]:
    if name not in cfg.models or cfg.models[name].kind != "learned":
        raise ConfigError(f"models.{name}: no learned model of that name")
    m = OmegaConf.to_container(cfg.models[name], resolve=True)
    bench = benchmark.load(cfg.paths.split, horizon=int(m["train"]["horizon"]))
    log_dir = Path(cfg.paths.train_logs) / name
    summary = train_model(hparams_from_config(m), m["train"], bench.train, Path(m["checkpoint"]),
                          log_dir=log_dir, accelerator=str(cfg.trainer.accelerator))
    (log_dir / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    return summary
