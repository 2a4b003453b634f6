"""drone_models: the discovered model's vehicle and the effects the format holds, as a
drone-models parameter file beside its model.json."""

import logging
from pathlib import Path

from omegaconf import DictConfig

from nanosysid.dataio import atomic_file, read_json_record
from nanosysid.export import drone_models
from nanosysid.vehicle import Vehicle
from stages.common import run_stage

log = logging.getLogger("nanosysid.drone_models")


def main(cfg: DictConfig) -> None:
    folder = Path(cfg.discover.out_dir)
    model = read_json_record(folder / "model.json", "nanosysid-discovered-1", "a discovered model", "discover")
    effects = {name: e["coefficients"] for name, e in model["effects"].items()}
    params, held, left = drone_models.parameters(Vehicle.from_mapping(model["vehicle"]), effects,
                                                 delay=float(model.get("delay", 0.0)))
    text = drone_models.toml_text(str(cfg.drone_models.name), params, held=held, left=left,
                                  source=str(cfg.drone_models.source))
    out = folder / "drone_models.toml"
    with atomic_file(out) as tmp:
        tmp.write_text(text)
    log.info("%s: [%s], drag held: %s; left out: %s", out, cfg.drone_models.name, ", ".join(held) or "none",
             ", ".join(left) or "none")


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
