"""Time of extract + sync + filter over the 15 recorded flights of the default dataset.

Uses the bags of `make repro` (raw/sim/bags); run that first. Also prints the time of
reading the bags alone (deserialising every message), the floor any extraction pays.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from omegaconf import OmegaConf
from rosbags.highlevel import AnyReader

from nanosysid.config import load_params
from nanosysid.bags.extract import extract_folder, find_bags
from nanosysid.bags.messages import typestore
from nanosysid.preprocess.filtering import FilterConfig, filter_folder
from nanosysid.preprocess.sync import SyncConfig, sync_folder


def main() -> dict[str, float]:
    cfg = load_params()
    r = cfg.preprocess
    bags_dir = Path(r.bags_dir)
    if not bags_dir.is_dir():
        raise SystemExit(f"{bags_dir}: no bags; run `make repro` first")
    topics = OmegaConf.to_container(r.topics, resolve=True)
    bags = find_bags(bags_dir)

    t0 = time.perf_counter()
    n_msgs = 0
    for bag in bags:
        with AnyReader([bag], default_typestore=typestore()) as reader:
            for c, _, raw in reader.messages():
                reader.deserialize(raw, c.msgtype)
                n_msgs += 1
    t_read = time.perf_counter() - t0

    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        t0 = time.perf_counter()
        extract_folder(bags_dir, d / "extract", topics)
        t1 = time.perf_counter()
        sync_folder(d / "extract", d / "sync", d / "reports",
                    SyncConfig.from_mapping(OmegaConf.to_container(r.sync)))
        t2 = time.perf_counter()
        filter_folder(d / "sync", d / "flights", d / "reports",
                      FilterConfig.from_mapping(OmegaConf.to_container(r.filter)))
        t3 = time.perf_counter()
    print(f"{len(bags)} bags, {n_msgs} messages")
    print(f"read + deserialise only: {t_read:.1f} s")
    print(f"extract {t1 - t0:.1f} s, sync {t2 - t1:.1f} s, filter {t3 - t2:.1f} s: "
          f"total {t3 - t0:.1f} s ({(t3 - t0) / t_read:.2f}x reading alone)")
    return {"bags": len(bags), "messages": n_msgs, "read_s": t_read, "extract_s": t1 - t0, "sync_s": t2 - t1,
            "filter_s": t3 - t2, "total_s": t3 - t0, "total_over_read": (t3 - t0) / t_read}


if __name__ == "__main__":
    main()
