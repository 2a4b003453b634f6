"""The output guard under hostile paths: every case ends in one clear error naming the path (or
rightly succeeds), nothing of the user's is lost, and nothing half-written is left behind.

Each case builds a small tree in a temporary folder, snapshots every byte in it, tries a write
through the project's own writers (:func:`nanosysid.dataio.atomic_file`,
:func:`~nanosysid.dataio.atomic_dir`, the flight and template writers, a stage run inside
:func:`nanosysid.guard.stage_run`), and compares the tree after with the tree before.
"""

from __future__ import annotations

import fcntl
import re
import os
from pathlib import Path

import numpy as np
import pytest

from nanosysid import guard, protocol
from nanosysid.dataio import OWNER, atomic_dir, atomic_file, read_flight_csv, write_flight_csv
from nanosysid.errors import ConfigError
from nanosysid.synthetic import synthetic_flights

CLASS = "data loss"


def snapshot(root: Path) -> dict[str, bytes | None]:
    """Every path under ``root`` with its bytes (None for a folder)."""
    def content(p: Path) -> bytes | None:
        if p.is_symlink():
            return b"-> " + os.readlink(p).encode()
        return None if p.is_dir() else p.read_bytes()

    return {str(p.relative_to(root)): content(p) for p in sorted(root.rglob("*"))}


def user_tree(root: Path) -> None:
    """What a user has: flights, a folder of notes, a file named like a backup."""
    (root / "data").mkdir()
    (root / "data" / "melon_20250101_run1.csv").write_text("t,x\n0,1\n")
    (root / "data" / "sub").mkdir()
    (root / "data" / "sub" / "notes.txt").write_text("mine")
    (root / "notes.md").write_text("# my notes\n")
    (root / ".out.backup.old").mkdir()
    (root / ".out.backup.old" / "keep.txt").write_text("a backup of mine")


def write_file(path: Path, **kw) -> None:
    with atomic_file(path, **kw) as tmp:
        tmp.write_text("new")


def write_dir(path: Path, **kw) -> None:
    with atomic_dir(path, **kw) as tmp:
        (tmp / "f.txt").write_text("new")


# (case, writer, output relative to root, inputs relative to root, the words the message must hold)
REFUSED = [
    ("file onto its input", write_file, "data/melon_20250101_run1.csv", ["data/melon_20250101_run1.csv"], "is the input"),
    ("file inside its input folder", write_file, "data/new.csv", ["data"], "lies inside the input"),
    ("file deep inside its input", write_file, "data/sub/new.txt", ["data"], "lies inside the input"),
    ("folder onto its input", write_dir, "data", ["data"], "is the input"),
    ("folder inside its input", write_dir, "data/out", ["data"], "lies inside the input"),
    ("folder containing its input", write_dir, ".", ["data"], "contains the input"),
    ("folder containing its input file", write_dir, "data", ["data/melon_20250101_run1.csv"], "contains the input"),
    ("file over a user's file", write_file, "notes.md", [], "no run of stage python wrote it"),
    ("file over a user's flight", write_file, "data/melon_20250101_run1.csv", [], "no run of stage python wrote it"),
    ("file where a user's folder is", write_file, "data/sub", [], "is a folder where the stage writes a file"),
    ("folder where a user's file is", write_dir, "notes.md", [], "is a file where the stage writes a folder"),
    ("folder over a user's folder", write_dir, "data", [], "holds files no run of stage python wrote"),
    ("folder over a user's nested folder", write_dir, "data/sub", [], "holds files no run of stage python wrote"),
    ("file under a user's file", write_file, "notes.md/x.json", [], "a parent of the output is a file"),
    ("folder under a user's file", write_dir, "notes.md/out", [], "a parent of the output is a file"),
]


@pytest.mark.parametrize("case,writer,out,inputs,words", REFUSED, ids=[c[0] for c in REFUSED])
def test_a_write_that_would_lose_data_is_refused_and_changes_nothing(tmp_path, case, writer, out, inputs, words):
    user_tree(tmp_path)
    before = snapshot(tmp_path)
    with pytest.raises(ConfigError) as e:
        writer(tmp_path / out, **({"inputs": [tmp_path / i for i in inputs]} if inputs else {}))
    named = (tmp_path / out).resolve().name
    assert words in str(e.value) and named in str(e.value), str(e.value)
    assert snapshot(tmp_path) == before


ACCEPTED = [
    ("new file", write_file, "out/new.json"),
    ("new folder", write_dir, "out"),
    ("an empty folder", write_dir, "empty"),
    ("a name with spaces", write_file, "my results/a b.json"),
    ("a name with non-ASCII letters", write_file, "résultats/données.json"),
    ("a folder named with spaces", write_dir, "my out"),
]


@pytest.mark.parametrize("case,writer,out", ACCEPTED, ids=[c[0] for c in ACCEPTED])
def test_a_fresh_output_is_written_and_written_again_without_touching_the_users(tmp_path, case, writer, out):
    user_tree(tmp_path)
    (tmp_path / "empty").mkdir()
    before = snapshot(tmp_path)
    writer(tmp_path / out)
    writer(tmp_path / out)  # the second run replaces what the first wrote
    after = snapshot(tmp_path)
    assert {k: v for k, v in after.items() if k in before} == before  # nothing of the user's changed
    new = set(after) - set(before)
    assert not [n for n in new if ".tmp" in n or ".old" in n]  # no temporaries left


@pytest.mark.parametrize("where", ["top", "nested"])
def test_a_users_file_inside_a_stages_folder_is_named_not_deleted(tmp_path, where):
    write_dir(tmp_path / "out")
    extra = tmp_path / "out" / ("mine.txt" if where == "top" else "sub/mine.txt")
    extra.parent.mkdir(exist_ok=True)
    extra.write_text("the user's")
    with pytest.raises(ConfigError, match=r"mine\.txt: not written by stage python"):
        write_dir(tmp_path / "out")
    assert extra.read_text() == "the user's" and (tmp_path / "out" / "f.txt").read_text() == "new"


@pytest.mark.parametrize("kind", ["file", "folder"])
def test_one_stage_never_replaces_anothers_output(tmp_path, kind, monkeypatch):
    monkeypatch.chdir(tmp_path)
    writer, out = (write_file, tmp_path / "o.json") if kind == "file" else (write_dir, tmp_path / "o")
    with guard.stage_run("sync"):
        writer(out)
    before = snapshot(tmp_path)
    with guard.stage_run("extract"), pytest.raises(ConfigError, match=r"written by stage sync, not by extract"):
        writer(out)
    assert snapshot(tmp_path) == before
    with guard.stage_run("sync"):
        writer(out)  # its own stage may


def test_a_stage_output_changed_by_hand_is_not_overwritten(tmp_path):
    write_file(tmp_path / "o.json")
    (tmp_path / "o.json").write_text("edited by hand")
    with pytest.raises(ConfigError, match=r"o\.json: changed since stage python wrote it"):
        write_file(tmp_path / "o.json")
    assert (tmp_path / "o.json").read_text() == "edited by hand"


@pytest.mark.parametrize("kind", ["file", "folder"])
def test_a_second_run_into_the_same_output_is_told_who_holds_it(tmp_path, kind):
    writer, out = (write_file, tmp_path / "o.json") if kind == "file" else (write_dir, tmp_path / "o")
    with guard.stage_run("train@lstm"):
        ctx = atomic_file(out) if kind == "file" else atomic_dir(out)
        with ctx as tmp:
            # another process holding the lock: a second open file description conflicts as one would
            with pytest.raises(ConfigError, match=rf"{out.name}: being written by stage train@lstm \(process {os.getpid()}\)"):
                writer(out)
            assert tmp.exists()  # the second run did not remove the first's temporary
            (tmp.write_text("first") if kind == "file" else (tmp / "f.txt").write_text("first"))
    assert (out.read_text() if kind == "file" else (out / "f.txt").read_text()) == "first"


def test_a_failed_write_leaves_the_old_output_its_record_and_no_temporary(tmp_path):
    write_dir(tmp_path / "out")
    before = snapshot(tmp_path)
    with pytest.raises(RuntimeError):
        with atomic_dir(tmp_path / "out") as tmp:
            (tmp / "half.txt").write_text("half")
            raise RuntimeError("killed")
    assert snapshot(tmp_path) == before
    write_dir(tmp_path / "out")  # and the next run may still replace it


@pytest.fixture
def flight_csv(tmp_path):
    f = synthetic_flights(["melon_20250101_run1"], 120, seed=0)[0]
    path = tmp_path / "data" / f"{f.name}.csv"
    write_flight_csv(f, path)
    return path


def test_a_template_written_onto_the_flight_it_scores_is_refused(flight_csv):
    flight = read_flight_csv(flight_csv)
    before = flight_csv.read_bytes()
    with pytest.raises(ConfigError, match="is the input"):
        protocol.write_template(lambda y0, u: np.repeat(y0[:, None], u.shape[1], 1), flight, flight_csv, horizon=5)
    assert flight_csv.read_bytes() == before


def test_a_flight_written_onto_itself_is_refused(flight_csv):
    flight = read_flight_csv(flight_csv)
    with pytest.raises(ConfigError, match="is the input"):
        write_flight_csv(flight, flight_csv)


def test_the_record_and_lock_live_beside_the_output_not_in_it(tmp_path):
    # the folder's bytes (what DVC hashes) hold the stage's files and the mark only
    write_dir(tmp_path / "out")
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [OWNER, "f.txt"]
    assert guard.record_path(tmp_path / "out").is_file()
    with open(guard.record_path(tmp_path / "out")) as fh:  # and the lock is free again
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)


def _stage_dir(path: Path, stage: str, files=("f.txt",)) -> None:
    with guard.stage_run(stage), atomic_dir(path) as tmp:
        for f in files:
            (tmp / f).write_text("the stage's")


def _record_gone(root: Path, out: str) -> None:
    guard.record_path(root / out).unlink()


# (case, what the user does to a stage's output folder "sync" before the stage "extract" or "sync"
# writes to the path given, the path, the writing stage, the words)
COPIES = [
    ("a cp -r copy of an output, then another stage into it",
     lambda r: os.system(f"cp -r '{r / 'sync'}' '{r / 'backup'}'"), "backup", "extract", "marked as the output of stage sync"),
    ("a cp -r copy of an output, then the same stage into it",
     lambda r: os.system(f"cp -r '{r / 'sync'}' '{r / 'backup'}'"), "backup", "sync", "a copy of stage sync's output"),
    ("a copy with the user's notes added",
     lambda r: (os.system(f"cp -r '{r / 'sync'}' '{r / 'backup'}'"), (r / "backup" / "notes.txt").write_text("mine")),
     "backup", "sync", "a copy of stage sync's output"),
    ("the record removed, a user's file added",
     lambda r: (_record_gone(r, "sync"), (r / "sync" / "notes.txt").write_text("mine")), "sync", "sync",
     "notes.txt: not written by stage sync"),
    ("the record removed, the output of another stage",
     lambda r: _record_gone(r, "sync"), "sync", "extract", "marked as the output of stage sync"),
    ("a copy moved over a new name, its record left behind",
     lambda r: os.replace(r / "sync", r / "moved"), "moved", "sync", "a copy of stage sync's output"),
]


@pytest.mark.parametrize("case,change,out,stage,words", COPIES, ids=[c[0] for c in COPIES])
def test_a_copy_of_an_output_is_never_taken_for_the_stages_own(tmp_path, monkeypatch, case, change, out, stage, words):
    monkeypatch.chdir(tmp_path)
    _stage_dir(Path("sync"), "sync")
    change(tmp_path)
    before = snapshot(tmp_path)
    with pytest.raises(ConfigError, match=words):
        _stage_dir(Path(out), stage, files=("other.txt",))
    assert snapshot(tmp_path) == before


def test_the_stages_own_output_restored_without_its_record_is_replaced(tmp_path, monkeypatch):
    # DVC's checkout brings the folder back without the record beside it: the mark tells it is
    # the stage's own, written here
    monkeypatch.chdir(tmp_path)
    _stage_dir(Path("sync"), "sync")
    _record_gone(tmp_path, "sync")
    _stage_dir(Path("sync"), "sync", files=("g.txt",))
    assert sorted(p.name for p in (tmp_path / "sync").iterdir()) == [OWNER, "g.txt"]


# (case, link name -> its target relative to the tree, writer, output, inputs, words)
LINKS = [
    ("file output that is a link to a user's file", ("link.md", "notes.md"), write_file, "link.md", [], "a link (to"),
    ("folder output that is a link to a user's folder", ("linked", "data/sub"), write_dir, "linked", [], "a link (to"),
    ("folder output that is a link to its input", ("linked", "data"), write_dir, "linked", ["data"], "a link (to"),
    ("dangling link as the output", ("gone", "nowhere"), write_file, "gone", [], "a link (to"),
    ("file inside a linked folder that is its input", ("view", "data"), write_file, "view/new.csv", ["data"],
     "lies inside the input"),
    ("folder inside a linked folder that is its input", ("view", "data"), write_dir, "view/out", ["data"],
     "lies inside the input"),
]


@pytest.mark.parametrize("case,link,writer,out,inputs,words", LINKS, ids=[c[0] for c in LINKS])
def test_a_link_never_leads_a_write_onto_what_it_points_at(tmp_path, case, link, writer, out, inputs, words):
    user_tree(tmp_path)
    (tmp_path / link[0]).symlink_to(tmp_path / link[1])
    before = snapshot(tmp_path)
    with pytest.raises(ConfigError, match=re.escape(words)):
        writer(tmp_path / out, **({"inputs": [tmp_path / i for i in inputs]} if inputs else {}))
    assert snapshot(tmp_path) == before
    assert (tmp_path / link[0]).is_symlink()
