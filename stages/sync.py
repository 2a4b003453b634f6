"""sync: align the clocks and lags of each flight's streams and resample them to 100 Hz."""

from omegaconf import DictConfig

from nanosysid.preprocess.sync import SyncConfig, sync_folder
from stages.common import plain, run_stage


def main(cfg: DictConfig) -> None:
    r = cfg.preprocess
    sync_folder(r.extract_dir, r.sync_dir, r.report_dir, SyncConfig.from_mapping(plain(r.sync)))


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
