"""Flight identity where data enters: a flight is in the data once, under one name, and no file
of flight data is left out without a word."""

from __future__ import annotations

import shutil

import pandas as pd

import pytest

from nanosysid import protocol
from nanosysid.dataio import Flight, read_flight_csv, write_flight_csv
from nanosysid.errors import DataError
from nanosysid.splitting import split_folder
from nanosysid.synthetic import synthetic_flights

CLASS = "silent acceptance"

NAMES = ["square_20250101_run1", "chirp_20250101_run1", "melon_20250101_run1", "melon_20250101_run2"]


@pytest.fixture(scope="module")
def flights():
    return synthetic_flights(NAMES, 70, seed=2)


@pytest.fixture
def folder(tmp_path, flights):
    """A benchmark folder (train/, test/) and a flat folder of the same flights."""
    for f in flights:
        part = "test" if f.name.startswith("melon") else "train"
        write_flight_csv(f, tmp_path / "bench" / part / f"{f.name}.csv")
        write_flight_csv(f, tmp_path / "flat" / f"{f.name}.csv")
    return tmp_path


def load_bench(root):
    return protocol.load(root / "bench", horizon=10)


def split_flat(root):
    return split_folder(root / "flat", root / "split", train=["square", "chirp"], test=["melon"], horizon=10)


def copy(src, dst):
    dst.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(src, dst)


def near_copy(src, dst, rows=slice(None), shift=0.0):
    """``src``'s rows ``rows`` written as the flight ``dst``, its time moved by ``shift`` s: no
    byte of the file is the same as ``src``'s, the samples are."""
    f = read_flight_csv(src)
    f = Flight(dst.stem, f.t[rows] + shift, f.u[rows], f.y[rows], {k: v[rows] for k, v in f.extra.items()})
    write_flight_csv(f, dst)


NEAR = [
    ("a test flight with its time moved by 100 s", dict(shift=100.0), "70 of its 70 distinct samples are the same"),
    ("the first 40 rows of a test flight", dict(rows=slice(0, 40)), "40 of its 70 distinct samples are the same"),
    ("the last 30 rows of a test flight", dict(rows=slice(-30, None)), "30 of its 70 distinct samples are the same"),
    ("25 rows from inside a test flight, moved 3 s", dict(rows=slice(20, 45), shift=3.0),
     "25 of its 70 distinct samples are the same"),
]


CASES = [
    # (case, change to the bench folder, change to the flat folder, words)
    ("run1 and run01", lambda r: copy(r / "bench/train/square_20250101_run1.csv", r / "bench/train/square_20250101_run01.csv"),
     lambda r: copy(r / "flat/square_20250101_run1.csv", r / "flat/square_20250101_run01.csv"), "the same flight as"),
    ("one name in two subfolders", lambda r: copy(r / "bench/train/chirp_20250101_run1.csv", r / "bench/train/b/chirp_20250101_run1.csv"),
     lambda r: copy(r / "flat/chirp_20250101_run1.csv", r / "flat/b/chirp_20250101_run1.csv"), "the same flight as"),
    ("a test flight under a training name", lambda r: copy(r / "bench/test/melon_20250101_run1.csv", r / "bench/train/square_20250101_run7.csv"),
     lambda r: copy(r / "flat/melon_20250101_run1.csv", r / "flat/square_20250101_run7.csv"), "the same samples as"),
    ("a training flight copied under another date", lambda r: copy(r / "bench/train/chirp_20250101_run1.csv", r / "bench/train/chirp_20250102_run1.csv"),
     lambda r: copy(r / "flat/chirp_20250101_run1.csv", r / "flat/chirp_20250102_run1.csv"), "the same samples as"),
    ("an upper-case extension", lambda r: (r / "bench/test/melon_20250101_run2.csv").rename(r / "bench/test/melon_20250101_run2.CSV"),
     lambda r: (r / "flat/melon_20250101_run2.csv").rename(r / "flat/melon_20250101_run2.CSV"), "'.CSV'"),
    ("a name of another form", None,
     lambda r: copy(r / "flat/chirp_20250101_run1.csv", r / "flat/chirp-final.csv"), "is not of the form"),
    ("a copy under a free name in train/", lambda r: copy(r / "bench/train/chirp_20250101_run1.csv", r / "bench/train/chirp-final.csv"),
     None, "the same samples as"),
    ("one flight in train and test", lambda r: copy(r / "bench/test/melon_20250101_run1.csv", r / "bench/train/melon_20250101_run1.csv"),
     None, "in both train/ and test/"),
] + [(case, lambda r, kw=kw: near_copy(r / "bench/test/melon_20250101_run1.csv", r / "bench/train/square_20250101_run7.csv", **kw),
      lambda r, kw=kw: near_copy(r / "flat/melon_20250101_run1.csv", r / "flat/square_20250101_run7.csv", **kw), words)
     for case, kw, words in NEAR]


MATRIX = [(entry, case, change, words) for case, bench, flat, words in CASES
          for entry, change in (("protocol.load", bench), ("split", flat)) if change is not None]


@pytest.mark.parametrize("entry,case,change,words", MATRIX, ids=[f"{m[0]}: {m[1]}" for m in MATRIX])
def test_a_flight_twice_or_out_of_sight_is_one_clear_error(folder, entry, case, change, words):
    action = load_bench if entry == "protocol.load" else split_flat
    change(folder)
    with pytest.raises(DataError, match=words) as e:
        action(folder)
    assert str(folder) in str(e.value)
    assert not (folder / "split").exists()


def test_the_clean_folders_load(folder):
    assert [f.name for f in load_bench(folder).test] == NAMES[2:]
    assert split_flat(folder)["test"]["samples"] == 2 * 70


def test_a_flight_at_rest_beside_another_is_no_copy(tmp_path):
    # two flights each repeating one sample (on the ground, motors off) share it: one distinct
    # sample, not a copy; the flights stay in
    rest = synthetic_flights(["square_20250101_run1", "melon_20250101_run1"], 70, seed=2)
    for f in rest:
        f.y[:30] = f.y[0] * 0 + rest[0].y[0]
        f.u[:30] = 0.0
        write_flight_csv(f, tmp_path / "flat" / f"{f.name}.csv")
    assert split_folder(tmp_path / "flat", tmp_path / "split", train=["square"], test=["melon"], horizon=10)


def changed_copy(src, dst, change):
    """``src``'s flight written as ``dst`` with ``change`` applied to its table: a copy by value."""
    df = pd.read_csv(src)
    change(df)
    dst.parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(dst, index=False)


BY_VALUE = [
    ("rounded to 6 decimals by another tool", lambda df: df.update(df.round(6))),
    ("every value times 1 + 1e-12", lambda df: df.update(df * (1 + 1e-12))),
    ("its positions mirrored (x and y negated)", lambda df: df.update(df[["x", "y"]] * -1)),
]


@pytest.mark.parametrize("case, change", BY_VALUE, ids=[c for c, _ in BY_VALUE])
def test_a_training_flight_copied_by_value_as_a_test_flight_is_refused(folder, case, change):
    # no sample of the copy is bit-identical to the training flight's: the check compares values
    changed_copy(folder / "flat/square_20250101_run1.csv", folder / "flat/melon_20250101_run7.csv", change)
    with pytest.raises(DataError, match=r"melon_20250101_run7.csv: (6[5-9]|70) of its 70 distinct samples are the same "
                                        r"samples to 4 decimals \(positions aside\) as in .*square_20250101_run1.csv"):
        split_flat(folder)
    assert not (folder / "split").exists()


def test_a_split_without_training_flights_or_of_a_file_is_refused(folder, tmp_path):
    with pytest.raises(DataError, match=r"no flight of the training trajectories \['hover'\]"):
        split_folder(folder / "flat", tmp_path / "s1", train=["hover"], test=["melon"], horizon=10)
    with pytest.raises(DataError, match=r"a file, not a folder of flights"):
        split_folder(folder / "flat/melon_20250101_run1.csv", tmp_path / "s2", train=["square"], test=["melon"],
                     horizon=10)
    with pytest.raises(DataError, match=r"no such folder \(/"):
        split_folder(tmp_path / "nowhere", tmp_path / "s3", train=["square"], test=["melon"], horizon=10)
    assert not any((tmp_path / s).exists() for s in ("s1", "s2", "s3"))


def test_a_header_padded_with_spaces_is_named_so(folder):
    path = folder / "flat/melon_20250101_run1.csv"
    text = path.read_text().splitlines()
    text[0] = " , ".join(text[0].split(","))
    path.write_text("\n".join(text) + "\n")
    with pytest.raises(DataError, match=r"the header's names are padded with spaces"):
        read_flight_csv(path)
