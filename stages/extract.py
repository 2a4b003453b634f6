"""extract: each recording -> one parquet table per stream, in SI units (ROS 2 bags, or the rig's
100 Hz logs: ``preprocess.format``)."""

from omegaconf import DictConfig

from nanosysid.bags.extract import extract_folder
from nanosysid.consistency import Expect
from nanosysid.errors import ConfigError
from nanosysid.rig.logs import LogSpec, extract_logs
from stages.common import plain, run_stage


def main(cfg: DictConfig) -> None:
    r = cfg.preprocess
    if r.format == "bags":
        extract_folder(r.bags_dir, r.extract_dir, plain(r.topics))
    elif r.format == "logs":
        spec = LogSpec.from_mapping(plain(cfg.rig.logs), min_samples=int(r.sync.min_samples))
        extract_logs(cfg.rig.paths.raw, r.extract_dir, spec,
                     Expect(float(cfg.vehicle.mass), float(cfg.vehicle.k_f), float(cfg.vehicle.gravity)))
    else:
        raise ConfigError(f"preprocess.format must be bags or logs, got {r.format!r}")


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
