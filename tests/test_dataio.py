"""Published CSV schema: round trip, and one clear error per kind of bad input."""

import json
import os
import re

import numpy as np
import pytest

from nanosysid import protocol, synthetic
from nanosysid.dataio import OWNER, atomic_dir, atomic_file, json_text, read_flight_csv, write_flight_csv
from nanosysid.errors import ConfigError, DataError
from nanosysid.splitting import split_folder


@pytest.fixture
def dataset(tmp_path):
    flights = synthetic.synthetic_flights(["square_d_run1", "melon_d_run1"], 80, seed=0)
    for part, f in zip(("train", "test"), flights):
        write_flight_csv(f, tmp_path / part / f"{f.name}.csv")
    return tmp_path, flights


def test_round_trip(dataset):
    root, flights = dataset
    bench = protocol.load(root, horizon=50)
    assert [f.name for f in bench.train] == ["square_d_run1"]
    got = bench.test[0]
    assert np.allclose(got.y, flights[1].y, rtol=1e-9, atol=1e-12)
    assert np.allclose(got.u, flights[1].u, rtol=1e-9)
    assert set(got.extra) >= {"ax_body", "ay_body", "az_body"}
    assert got.trajectory == "melon" and got.run == 1


def test_same_flight_same_bytes(tmp_path):
    a, b = (synthetic.synthetic_flights(["melon_d_run1"], 50, seed=5, noise=0.01)[0] for _ in range(2))
    write_flight_csv(a, tmp_path / "a.csv")
    write_flight_csv(b, tmp_path / "b.csv")
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()


def corrupt(path, fn):
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    rows = [line.split(",") for line in lines[1:]]
    header, rows = fn(header, rows)
    path.write_text("\n".join([",".join(header)] + [",".join(r) for r in rows]) + "\n")


def set_cell(col, row, value):
    def fn(header, rows):
        rows[row][header.index(col)] = value
        return header, rows

    return fn


def drop_col(col):
    def fn(header, rows):
        i = header.index(col)
        return header[:i] + header[i + 1 :], [r[:i] + r[i + 1 :] for r in rows]

    return fn


@pytest.mark.parametrize(
    "damage, pattern",
    [
        (drop_col("vz"), r"missing column\(s\) 'vz'"),
        (set_cell("wy", 17, "fast"), r"column 'wy', row 17 \(line 19\): non-numeric value 'fast'"),
        (set_cell("x", 3, "nan"), r"column 'x', row 3 \(line 5\): missing value \(NaN\)"),
        (set_cell("x", 4, ""), r"column 'x', row 4 \(line 6\): missing value \(NaN\)"),
        (set_cell("vy", 7, " -inf"), r"column 'vy', row 7 \(line 9\): infinite value '-inf'"),
        (lambda h, r: (h, r[:20] + [r[20][:-1]] + r[21:]), r"column 'az_body', row 20 \(line 22\): missing value \(NaN\)"),
        (set_cell("t", 30, "0.1"), r"column 't', row 30 \(line 32\): time does not increase"),
        (set_cell("qw", 12, "1.5"), r"column 'qx/qy/qz/qw', row 12 \(line 14\): quaternion norm"),
    ],
)
def test_bad_input_names_file_column_and_row(dataset, damage, pattern):
    root, _ = dataset
    path = root / "test" / "melon_d_run1.csv"
    corrupt(path, damage)
    with pytest.raises(DataError, match=pattern) as e:
        protocol.load(root)
    assert str(path) in str(e.value)


def test_values_are_the_texts_correctly_rounded(dataset):
    """Every value is the double nearest its text, as Python's ``float`` reads it: 17 significant
    digits, long decimal expansions, exponents, subnormals, signs and padding."""
    root, _ = dataset
    path = root / "test" / "melon_d_run1.csv"
    rng = np.random.default_rng(3)
    x = rng.standard_normal(60) * 10.0 ** rng.integers(-15, 15, 60)
    texts = ([repr(float(v)) for v in x[:20]] + [f"{v:.17g}" for v in x[20:40]] + [f"{v:.25e}" for v in x[40:50]]
             + ["-0.0", "4.9e-324", "2.2250738585072011e-308", "0.30000000000000004", "9007199254740993",
                " 1.5", "2.5 ", "+3", ".5", "7.", "1E3", "0.1000000000000000055511151231257827"])
    corrupt(path, lambda h, r: (h, [row[:h.index("ax_body")] + [texts[i]] + row[h.index("ax_body") + 1:]
                                    for i, row in enumerate(r[:len(texts)])] + r[len(texts):]))
    got = read_flight_csv(path).extra["ax_body"][:len(texts)]
    assert got.view(np.int64).tolist() == np.array([float(s) for s in texts]).view(np.int64).tolist()


def test_repeated_timestamp_is_rejected(dataset):
    root, _ = dataset
    path = root / "train" / "square_d_run1.csv"
    corrupt(path, lambda h, r: (h, r[:10] + [r[9]] + r[10:]))
    with pytest.raises(DataError, match=r"square_d_run1.csv: column 't', row 10 \(line 12\): time does not increase"):
        protocol.load(root)


def test_too_few_rows(dataset):
    root, _ = dataset
    with pytest.raises(DataError, match=r"square_d_run1.csv: 80 rows, fewer than the 101 one window needs"):
        protocol.load(root, horizon=100)


def test_not_a_csv_and_missing_folder(tmp_path, dataset):
    root, _ = dataset
    (root / "test" / "melon_d_run1.csv").write_bytes(b"")
    with pytest.raises(DataError, match="not a readable CSV"):
        protocol.load(root)
    with pytest.raises(DataError, match="no such folder"):
        protocol.load(tmp_path / "nowhere")


def test_small_quaternion_drift_is_accepted(tmp_path):
    f = synthetic.synthetic_flights(["melon_d_run1"], 60, seed=0)[0]
    f.y[:, 6:10] *= 1.0009
    write_flight_csv(f, tmp_path / "f.csv")
    assert len(read_flight_csv(tmp_path / "f.csv")) == 60


def test_atomic_dir_keeps_old_contents_on_failure(tmp_path):
    out = tmp_path / "out"
    with atomic_dir(out) as tmp:
        (tmp / "keep.txt").write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_dir(out) as tmp:
            (tmp / "partial.txt").write_text("new")
            raise RuntimeError("stage failed")
    assert sorted(os.listdir(out)) == [OWNER, "keep.txt"] and (out / "keep.txt").read_text() == "old"
    # no temporary left behind; the record of who wrote it beside it
    assert sorted(os.listdir(tmp_path)) == [".out.nanosysid", "out"]


def test_a_folder_no_stage_wrote_is_never_replaced(tmp_path):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("the user's")
    with pytest.raises(ConfigError, match=r"mine: holds files no run of stage python wrote"):
        with atomic_dir(mine) as tmp:
            (tmp / "f").write_text("x")
    assert os.listdir(mine) == ["notes.txt"]
    (tmp_path / "empty").mkdir()
    with atomic_dir(tmp_path / "empty") as tmp:  # an empty folder is fine
        (tmp / "f").write_text("x")


@pytest.mark.parametrize("out", ["bags", "bags/extract", "."])
def test_an_output_overlapping_its_input_is_refused(tmp_path, out):
    bags = tmp_path / "bags"
    bags.mkdir()
    (bags / "flight.mcap").write_text("data")
    with pytest.raises(ConfigError, match=r"the output (is|lies inside|contains) the input"):
        with atomic_dir(tmp_path / out, inputs=[bags]) as tmp:
            (tmp / "f").write_text("x")
    assert os.listdir(bags) == ["flight.mcap"]


def test_written_files_and_folders_get_the_users_umask(tmp_path):
    old = os.umask(0o022)
    try:
        with atomic_file(tmp_path / "a.txt") as tmp:
            tmp.write_text("x")
        with atomic_dir(tmp_path / "d") as tmp:
            (tmp / "f").write_text("y")
    finally:
        os.umask(old)
    assert (tmp_path / "a.txt").stat().st_mode & 0o777 == 0o644
    assert (tmp_path / "d").stat().st_mode & 0o777 == 0o755


def test_leftovers_of_a_killed_write_are_removed_by_the_next_and_only_ours(tmp_path):
    (tmp_path / ".out.nanosysid-abc123.tmp").mkdir()  # what a killed atomic_dir leaves
    (tmp_path / ".out.nanosysid-abc123.tmp" / "half.csv").write_text("1,2\n")
    (tmp_path / ".m.json.nanosysid-xyz.tmp").write_text("{")  # and a killed atomic_file
    (tmp_path / ".notes.txt").write_text("not ours")
    (tmp_path / ".out.backup.old").mkdir()  # the user's, named like a backup
    (tmp_path / ".m.json.mine.tmp").write_text("the user's")
    with atomic_dir(tmp_path / "out") as tmp:
        (tmp / "f").write_text("y")
    with atomic_file(tmp_path / "m.json") as tmp:
        tmp.write_text("{}")
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        ".m.json.mine.tmp", ".m.json.nanosysid", ".notes.txt", ".out.backup.old", ".out.nanosysid", "m.json", "out"]
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [OWNER, "f"]


def scale_column(col, factor, rows=slice(None)):
    def fn(header, rows_):
        i = header.index(col)
        for r in rows_[rows]:
            r[i] = repr(float(r[i]) * factor)
        return header, rows_

    return fn


def drop_rows(a, b):
    return lambda h, r: (h, r[:a] + r[b:])


def jitter_row(row, dt):
    def fn(header, rows):
        i = header.index("t")
        rows[row][i] = repr(float(rows[row][i]) + dt)
        return header, rows

    return fn


@pytest.mark.parametrize("damage, pattern", [
    # 50 Hz: every other row of a 100 Hz flight, t as it was
    (lambda h, r: (h, r[::2]), r"column 't': samples 0.02 s apart \(50 Hz\); the benchmark is sampled at 100 Hz"),
    (scale_column("t", 1000.0), r"column 't': samples 10 s apart \(0.1 Hz\).*is 't' in seconds\?"),
    (drop_rows(20, 60), r"column 't', row 20 \(line 22\): a gap of 0.41 s after 0.19"),
    (jitter_row(30, 0.004), r"column 't', row 30 \(line 32\): a step of 0.014 s after 0.29"),
    (set_cell("x", 9, "inf"), r"column 'x', row 9 \(line 11\): infinite value 'inf'"),
    (lambda h, r: (h[:-1] + ["x"], r), r"column\(s\) 'x' appear more than once in the header"),
])
def test_sample_rate_gaps_and_header_are_checked(dataset, damage, pattern):
    root, _ = dataset
    path = root / "test" / "melon_d_run1.csv"
    corrupt(path, damage)
    with pytest.raises(DataError, match=pattern) as e:
        protocol.load(root, horizon=10)
    assert str(path) in str(e.value) and "np.float64" not in str(e.value)


def test_a_flight_in_train_and_test_is_refused(dataset):
    root, _ = dataset
    (root / "test" / "square_d_run1.csv").write_bytes((root / "train" / "square_d_run1.csv").read_bytes())
    with pytest.raises(DataError, match=r"flight square_d_run1 is in both train/ and test/"):
        protocol.load(root)


def test_file_names_links_and_folders_are_checked(dataset):
    root, _ = dataset
    (root / "train" / "chirp_d_run2.csv").symlink_to(root / "nowhere.csv")
    with pytest.raises(DataError, match=r"chirp_d_run2.csv: no such file \(a broken link\)"):
        protocol.load(root)
    (root / "train" / "chirp_d_run2.csv").unlink()
    (root / "train" / "chirp_d_run3.csv").mkdir()
    with pytest.raises(DataError, match=r"chirp_d_run3.csv: a folder, not a flight CSV file"):
        protocol.load(root)


def own_flights(root, names, parts=None):
    """Flights of the schema written under ``root`` with the given file names (distinct samples)."""
    flights = synthetic.synthetic_flights([f"f_d_run{i}" for i in range(len(names))], 40, seed=3)
    for name, f in zip(names, flights):
        write_flight_csv(f, root / name)
    return flights


def test_flights_of_any_name_in_a_train_and_test_layout_are_named_from_the_file(tmp_path):
    own_flights(tmp_path / "mine", ["train/Hover 03.csv", "train/loop.csv", "test/Figure_Eight-run2.csv"])
    bench = protocol.load(tmp_path / "mine", horizon=10)
    assert [(f.name, f.trajectory, f.run) for f in bench.train] == [("hover_own_run3", "hover", 3),
                                                                    ("loop_own_run1", "loop", 1)]
    assert [(f.trajectory, f.run) for f in bench.test] == [("figure-eight", 2)]
    # the split follows the folders where no list names the trajectory, and writes the names every
    # later stage reads trajectory and run from
    summary = split_folder(tmp_path / "mine", tmp_path / "split", train=["square"], test=["melon"], horizon=10)
    assert sorted(p.name for p in (tmp_path / "split" / "train").iterdir()) == ["hover_own_run3.csv", "loop_own_run1.csv"]
    assert list(summary["test"]["flights"]) == ["figure-eight_own_run2"]
    # a list still moves a trajectory across the folders (an ablation of the split)
    split_folder(tmp_path / "mine", tmp_path / "split2", train=["figure-eight"], test=["loop"], horizon=10)
    assert sorted(p.name for p in (tmp_path / "split2" / "test").iterdir()) == ["loop_own_run1.csv"]
    assert "figure-eight_own_run2.csv" in {p.name for p in (tmp_path / "split2" / "train").iterdir()}


def test_a_flat_folder_of_free_names_is_refused_with_the_ways_to_name_them(tmp_path):
    own_flights(tmp_path / "flat", ["my flight.csv", "melon_d_run1.csv"])
    with pytest.raises(DataError, match=r"my flight.csv: flight name 'my flight' is not of the form .*manifest.csv"):
        split_folder(tmp_path / "flat", tmp_path / "split", train=["x"], test=["melon"], horizon=10)
    assert not (tmp_path / "split").exists()


def test_a_manifest_names_trajectory_run_and_part_of_each_file(tmp_path):
    own_flights(tmp_path / "m", ["a.csv", "b.csv", "sub/c.csv"])
    (tmp_path / "m" / "manifest.csv").write_text("file,trajectory,run,part\na.csv,Spiral,2,\nb.csv,spiral,5,\n"
                                                  "sub/c.csv,dive,1,test\n")
    split_folder(tmp_path / "m", tmp_path / "split", train=["spiral"], test=[], horizon=10)
    assert sorted(p.name for p in (tmp_path / "split" / "train").iterdir()) == ["spiral_own_run2.csv",
                                                                               "spiral_own_run5.csv"]
    assert [p.name for p in (tmp_path / "split" / "test").iterdir()] == ["dive_own_run1.csv"]
    bench = protocol.load(tmp_path / "split", horizon=10)
    assert [(f.trajectory, f.run) for f in bench.train] == [("spiral", 2), ("spiral", 5)]


@pytest.mark.parametrize("manifest,words", [
    ("file,trajectory\na.csv,x\n", r"manifest.csv: missing column\(s\) 'run'"),
    ("file,trajectory,run\na.csv,x,two\nb.csv,x,2\n", r"manifest.csv: row 1 \(line 2\), field 'run': 'two' is not a whole"),
    ("file,trajectory,run\na.csv,x,1\nb.csv,9lives,2\n", r"row 2 \(line 3\), field 'trajectory': '9lives' is not a name"),
    ("file,trajectory,run,part\na.csv,x,1,val\nb.csv,x,2,\n", r"field 'part': 'val' is neither 'train' nor 'test'"),
    ("file,trajectory,run\na.csv,x,1\n", r"b.csv: not listed in .*manifest.csv"),
    ("file,trajectory,run\na.csv,x,1\nb.csv,x,2\nc.csv,x,3\n", r"manifest.csv: row for file 'c.csv': no such flight file"),
    ("file,trajectory,run\na.csv,x,1\nb.csv,x,1\n", r"b.csv: the same flight as .*a.csv"),
    ("file,trajectory,run\na.csv,x,1\n../b.csv,x,2\n", r"field 'file': '../b.csv' is not a path inside"),
])
def test_a_bad_manifest_is_one_error_naming_row_and_field(tmp_path, manifest, words):
    own_flights(tmp_path / "m", ["a.csv", "b.csv"])
    (tmp_path / "m" / "manifest.csv").write_text(manifest)
    with pytest.raises(DataError, match=words):
        split_folder(tmp_path / "m", tmp_path / "split", train=["x"], test=[], horizon=10)
    assert not (tmp_path / "split").exists()


def test_an_empty_test_folder_is_one_clear_error(dataset):
    root, _ = dataset
    for f in (root / "test").glob("*.csv"):
        f.unlink()
    with pytest.raises(DataError, match=rf"{re.escape(str(root / 'test'))}: no flight CSV files"):
        protocol.load(root)


def test_json_the_project_writes_is_strict_and_says_what_was_not_finite():
    text = json_text({"simerr": {"p": float("inf"), "v": 1.5}, "mae": [np.float64("nan"), 2.0]})

    def refuse(constant):
        raise ValueError(f"non-standard JSON constant {constant}")

    d = json.loads(text, parse_constant=refuse)
    assert d["simerr"] == {"p": None, "v": 1.5} and d["mae"] == [None, 2.0]
    assert d["non_finite"] == ["simerr.p: inf", "mae[0]: nan"]


def test_a_text_column_beside_the_schema_is_left_out_with_one_warning(dataset, caplog):
    root, flights = dataset
    path = root / "test" / "melon_d_run1.csv"

    def labelled(header, rows):
        return header + ["pilot", "note"], [r + ["anna", "gusty" if i == 3 else ""] for i, r in enumerate(rows)]

    corrupt(path, labelled)
    with caplog.at_level("WARNING", logger="nanosysid.dataio"):
        got = read_flight_csv(path)
    assert "pilot" not in got.extra and "note" not in got.extra
    np.testing.assert_allclose(got.y, flights[1].y, rtol=1e-9, atol=1e-12)
    warned = [r.getMessage() for r in caplog.records]
    assert len(warned) == 1 and "'pilot', 'note'" in warned[0] and str(path) in warned[0], warned
    # a column of the schema stays one clear error
    corrupt(path, set_cell("wy", 17, "fast"))
    with pytest.raises(DataError, match=r"column 'wy', row 17 \(line 19\): non-numeric value 'fast'"):
        read_flight_csv(path)
