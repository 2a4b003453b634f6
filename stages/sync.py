"""sync: align the clocks and lags of each flight's streams and resample them to 100 Hz."""

from omegaconf import DictConfig, OmegaConf

from nanosysid.cli import run_stage
from nanosysid.recording import pipeline
from nanosysid.recording.sync import SyncConfig


def main(cfg: DictConfig) -> None:
    r = cfg.recording
    sync_cfg = SyncConfig.from_mapping(OmegaConf.to_container(r.sync, resolve=True))
    pipeline.sync_folder(r.extract_dir, r.sync_dir, r.report_dir, sync_cfg)


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
