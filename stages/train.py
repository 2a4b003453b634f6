"""train: fit one learned model on the training flights (multi-step rollout loss)."""

from pathlib import Path
from typing import Any

from hydra.utils import instantiate
from omegaconf import DictConfig

from nanosysid import benchmark
from nanosysid.dataio import atomic_dir, json_text
from nanosysid.errors import ConfigError
from nanosysid.identify import identified_vehicle
from nanosysid.models.physics import PhysicsStep
from nanosysid.models.training import train_model
from nanosysid.vehicle import Vehicle
from stages.common import model_options, plain, run_stage


def network_spec(m: dict[str, Any]) -> dict[str, Any]:
    """``{"name", "options"}`` of a learned model's ``network`` block (what its checkpoint stores)."""
    net = dict(m["network"])
    return {"name": net.pop("name"), "options": net}


def physics_base(m: dict[str, Any]) -> PhysicsStep | None:
    """The physics step of a ``physics`` block (physics + residual), k_F and k_M identified."""
    p = m.get("physics")
    if p is None:
        return None
    v = identified_vehicle(Vehicle.from_mapping(p["vehicle"]), p.get("identified"))
    return PhysicsStep(v, dt=float(p["dt"]), substeps=int(p["substeps"]), angular_dynamics=False)


def optimiser_parts(t: DictConfig, name: str):
    """The model's optimiser and scheduler factories, tried once on a probe parameter so that a bad
    argument (``lr=abc``, a keyword the class does not take) is one error before training starts."""
    import torch

    try:
        optimizer = instantiate(t.optimizer)
        probe = optimizer([torch.zeros(1, requires_grad=True)])
        scheduler = instantiate(t.scheduler) if t.scheduler else None
        if scheduler is not None:
            scheduler(probe)
    except Exception as e:  # Hydra's InstantiationException, or the class's own TypeError / ValueError
        first = str(e).strip().splitlines()[-1] if str(e).strip() else type(e).__name__
        raise ConfigError(f"models.{name}.train.optimizer / scheduler: cannot build them ({first})") from None
    return optimizer, scheduler


def main(cfg: DictConfig, name: str) -> dict[str, Any]:
    m = model_options(cfg, name)
    if m["kind"] != "learned":
        raise ConfigError(f"models.{name}: not a learned model (kind {m['kind']!r})")
    t = cfg.models[name].train
    optimizer, scheduler = optimiser_parts(t, name)
    bench = benchmark.load(cfg.paths.split, horizon=int(t.horizon))
    # the training curves are written beside the old ones and swapped in whole at the end, so
    # a killed run leaves the previous model's logs, not a mixture
    with atomic_dir(Path(cfg.paths.train_logs) / name, inputs=[cfg.paths.split]) as log_dir:
        summary = train_model(
            network_spec(m), bench.train, Path(m["checkpoint"]), physics=physics_base(m),
            optimizer=optimizer, scheduler=scheduler,
            horizon=int(t.horizon), stride=int(t.stride), batch_size=int(t.batch_size), epochs=int(t.epochs),
            patience=int(t.patience), seed=int(t.seed), val_runs=plain(t.val_runs), log_dir=log_dir,
            accelerator=str(cfg.trainer.accelerator), devices=plain(cfg.trainer.devices))
        (log_dir / "summary.json").write_text(json_text(summary))
    return summary


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__, name_arg="model"))
