"""train: fit one learned model on the training flights (multi-step rollout loss)."""

from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from nanosysid import protocol
from nanosysid.dataio import atomic_dir, json_text
from nanosysid.errors import ConfigError
from nanosysid.models.training import network_spec, optimiser_parts, physics_base, train_model
from stages.common import model_options, plain, run_stage


def main(cfg: DictConfig, name: str) -> dict[str, Any]:
    m = model_options(cfg, name)
    if m["kind"] != "learned":
        raise ConfigError(f"models.{name}: not a learned model (kind {m['kind']!r})")
    t = cfg.models[name].train
    if cfg.trainer.get("every_model"):  # laid over every learned model's own (the quick profile's)
        t = OmegaConf.merge(t, cfg.trainer.every_model)
    optimizer, scheduler = optimiser_parts(plain(t.optimizer), plain(t.scheduler), f"models.{name}.train")
    bench = protocol.load(cfg.paths.split, horizon=int(t.horizon))
    # the training curves are written beside the old ones and swapped in whole at the end, so
    # a killed run leaves the previous model's logs, not a mixture
    with atomic_dir(Path(cfg.paths.train_logs) / name, inputs=[cfg.paths.split]) as log_dir:
        summary = train_model(
            network_spec(m), bench.train, Path(m["checkpoint"]), physics=physics_base(m),
            optimizer=optimizer, scheduler=scheduler,
            horizon=int(t.horizon), horizon_decay=float(t.horizon_decay), stride=int(t.stride), batch_size=int(t.batch_size), epochs=int(t.epochs),
            patience=int(t.patience), seed=int(t.seed), val_runs=plain(t.val_runs), log_dir=log_dir,
            accelerator=str(cfg.trainer.accelerator), devices=plain(cfg.trainer.devices), compile=bool(t.compile),
            threads=int(t.threads))
        (log_dir / "summary.json").write_text(json_text(summary))
    return summary


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__, name_arg="model"))
