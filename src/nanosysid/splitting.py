"""Train/test split by trajectory, never by sample (neighbouring samples would leak)."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path
from typing import Sequence

from nanosysid.consistency import Expect, check_flight
from nanosysid.dataio import atomic_dir, check_distinct, flight_catalog, json_text, parse_flight_name, read_flight_csv
from nanosysid.errors import ConfigError, DataError

__all__ = ["split_folder"]

log = logging.getLogger(__name__)


def split_folder(
    src: str | Path,
    dst: str | Path,
    *,
    train: Sequence[str],
    test: Sequence[str],
    horizon: int,
    expect: Expect | None = None,
) -> dict:
    """Copy each validated flight CSV under ``src`` into ``dst/train`` or ``dst/test``.

    A flight goes to the part whose list names its trajectory; a flight of another trajectory
    goes to the part its ``train/``/``test/`` folder or ``src``'s manifest gives it, else it is
    left out. Each copy is named ``<trajectory>_<session>_run<k>.csv``
    (:func:`nanosysid.dataio.flight_catalog`), the form every later stage reads the trajectory
    and run from. ``dst`` is replaced only when the whole split succeeded. With ``expect`` (the
    vehicle's mass, k_F, gravity), every flight's columns are checked against each other first
    (:mod:`nanosysid.consistency`): a flight in another unit or convention is refused.

    Returns:
        Summary with the flights and sample counts of each part (also ``dst/split.json``).
    """
    src, dst = Path(src), Path(dst)
    both = set(train) & set(test)
    if both:
        raise ConfigError(f"split: trajectories {sorted(both)} are listed for both train and test")
    if src.is_file():
        raise DataError(f"{src}: a file, not a folder of flights (data.flights_dir names the folder that holds them)")
    if not src.is_dir():
        raise DataError(f"{src}: no such folder ({src.resolve()})")
    files = flight_catalog(src)
    if not files:
        raise DataError(f"{src}: no flight CSV files found (in {src.resolve()})")
    parts: dict[str, list] = {"train": [], "test": []}
    for f in files:
        trajectory, _ = parse_flight_name(f.name)
        part = "train" if trajectory in train else "test" if trajectory in test else f.part
        if part is None:
            log.info("split: %s left out (trajectory %r in neither list)", f.path.name, trajectory)
            continue
        if f.name != f.path.stem:
            log.info("split: %s -> %s/%s.csv", f.path.relative_to(src), part, f.name)
        parts[part].append(f)
    if not parts["test"]:
        raise DataError(f"{src}: no flight of the test trajectories {list(test)}")
    if not parts["train"]:
        raise DataError(f"{src}: no flight of the training trajectories {list(train)} (nor in a train/ folder or the "
                        "manifest's train part); the models need training flights")
    summary: dict = {}
    read = {f: read_flight_csv(f.path, min_rows=horizon + 1) for flist in parts.values() for f in flist}
    if expect is not None:
        for flight in read.values():
            check_flight(flight, expect)
    check_distinct(list(read.values()))
    with atomic_dir(dst, inputs=[src]) as tmp:
        for part, flist in parts.items():
            (tmp / part).mkdir()
            samples = {}
            for f in flist:
                samples[f.name] = len(read[f])
                shutil.copyfile(f.path, tmp / part / f"{f.name}.csv")
            summary[part] = {"flights": samples, "samples": sum(samples.values())}
        (tmp / "split.json").write_text(json_text(summary))
    log.info(
        "split: train %d flights / %d samples, test %d flights / %d samples",
        len(parts["train"]), summary["train"]["samples"], len(parts["test"]), summary["test"]["samples"],
    )
    return summary
