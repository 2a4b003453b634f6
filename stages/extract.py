"""extract: each ROS 2 bag -> one parquet table per stream, in SI units."""

import logging
from pathlib import Path
from typing import Any, Mapping

from omegaconf import DictConfig
from tqdm.auto import tqdm

from nanosysid.bags.extract import STREAM_COLUMNS, extract_bag, find_bags
from nanosysid.dataio import atomic_dir, check_finite
from stages.common import plain, run_stage

log = logging.getLogger("nanosysid.extract")


def extract_folder(bags_dir: Path, out_dir: Path, topics: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """Every bag of ``bags_dir`` to ``out_dir/<flight>/<stream>.parquet``."""
    bags = find_bags(bags_dir)
    with atomic_dir(out_dir, inputs=[bags_dir]) as tmp:
        for bag in tqdm(bags, desc="extract", unit="bag", disable=None):
            tables = extract_bag(bag, topics)
            (tmp / bag.name).mkdir()
            for stream, df in tables.items():
                # a motor's NaN is a missed reading, marked so for sync
                check_finite(df, f"{bag}: stream {stream}", allowed=STREAM_COLUMNS["motors"] if stream == "motors" else ())
                df.to_parquet(tmp / bag.name / f"{stream}.parquet", index=False)
    log.info("extract: %d bags from %s", len(bags), bags_dir)
    return [b.name for b in bags]


def main(cfg: DictConfig) -> None:
    r = cfg.recording
    extract_folder(r.bags_dir, r.extract_dir, plain(r.topics))


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
