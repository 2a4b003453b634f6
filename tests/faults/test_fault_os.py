"""Operating-system faults while a stage writes: one line naming the path and what to do, exit
code 2, no traceback, and nothing half-written left behind."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

from nanosysid import dataio
from stages.common import run_stage


FAULTS = [
    (errno.ENOSPC, "No space left on device", "the disk is full"),
    (errno.EDQUOT, "Disk quota exceeded", "quota"),
    (errno.EROFS, "Read-only file system", "read-only"),
    (errno.EACCES, "Permission denied", "no permission"),
    (errno.EPERM, "Operation not permitted", "not permitted"),
    (errno.EIO, "Input/output error", "check the path and the disk"),
    (errno.ENAMETOOLONG, "File name too long", "shorter path"),
]

CLASS = "operating-system fault"


@pytest.mark.parametrize("where", ["file", "folder"])
@pytest.mark.parametrize("code,text,hint", FAULTS, ids=[f[1] for f in FAULTS])
def test_a_fault_while_writing_is_one_line_and_leaves_nothing(tmp_path, monkeypatch, capsys, params, where, code, text,
                                                                 hint):
    out = tmp_path / "results" / ("scores.json" if where == "file" else "eval")
    real_replace = os.replace

    def failing_replace(src, dst):
        if Path(dst) == out:
            raise OSError(code, text, str(dst))
        return real_replace(src, dst)

    def main(cfg):
        monkeypatch.setattr(dataio.os, "replace", failing_replace)
        if where == "file":
            with dataio.atomic_file(out) as tmp:
                tmp.write_text("{}")
        else:
            with dataio.atomic_dir(out) as tmp:
                (tmp / "scores.json").write_text("{}")

    main.__module__ = "stages.faulty"
    assert run_stage(main, description="", argv=["--params", str(params)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith(f"error: {out}: {text}") and hint in err, err
    # no temporary, no output, no record of a write that never happened, nor the folder made for it
    assert not out.parent.exists(), list(out.parent.iterdir())


@pytest.mark.parametrize("name", ["with space", "non-ascii-é", "quote's"])
def test_unusual_characters_in_an_output_path_are_written(tmp_path, name):
    out = tmp_path / name / "x.json"
    with dataio.atomic_file(out) as tmp:
        tmp.write_text("{}")
    assert out.read_text() == "{}"


def test_an_output_whose_parent_is_a_file_is_one_clear_error(tmp_path):
    (tmp_path / "a").write_text("a file")
    with pytest.raises(dataio.ConfigError, match=r"a parent of the output is a file"):
        with dataio.atomic_file(tmp_path / "a" / "b" / "c.json") as tmp:
            tmp.write_text("{}")
    assert (tmp_path / "a").read_text() == "a file"


@pytest.mark.parametrize("raised", [
    OSError(errno.ENOSPC, "No space left on device", "/the/input/flight.csv"),  # a copy names its source
    OSError("Error writing bytes to file. Detail: [errno 28] No space left on device"),  # a library names nothing
], ids=["an input named", "no path named"])
def test_a_full_disk_names_the_output_being_written(tmp_path, capsys, params, raised):
    out = tmp_path / "results" / "split"

    def main(cfg):
        with dataio.atomic_dir(out) as tmp:
            (tmp / "a.csv").write_text("x")
            raise raised

    main.__module__ = "stages.faulty"
    assert run_stage(main, description="", argv=["--params", str(params)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"error: {out}: No space left on device; the disk is full: free space or choose an output on " \
                  "another disk", err
    assert not out.parent.exists()


@pytest.mark.parametrize("before", [False, True], ids=["first run", "a run before"])
def test_a_stage_failing_at_a_later_output_leaves_its_earlier_ones_as_they_were(tmp_path, capsys, params, before):
    """A stage writes its outputs one after another; one refused by a full disk takes back the
    ones written before it in the same run: a report is never left with some of its figures."""
    out = tmp_path / "report"
    table, figures = out / "table.md", out / "figures"

    def writes(fail):
        def main(cfg):
            with dataio.atomic_file(table) as tmp:
                tmp.write_text("new" if fail else "old")
            with dataio.atomic_dir(figures) as tmp:
                (tmp / "a.png").write_text("new" if fail else "old")
                if fail:
                    raise OSError(errno.ENOSPC, "No space left on device")
        main.__module__ = "stages.faulty"
        return main

    if before:
        assert run_stage(writes(False), description="", argv=["--params", str(params)]) == 0
        listing = sorted(p.name for p in out.iterdir())
        record = (out / ".table.md.nanosysid").read_text()
    assert run_stage(writes(True), description="", argv=["--params", str(params)]) == 2
    assert capsys.readouterr().err.strip().startswith(f"error: {figures}: No space left on device")
    if before:
        assert sorted(p.name for p in out.iterdir()) == listing
        assert table.read_text() == "old" and (figures / "a.png").read_text() == "old"
        assert (out / ".table.md.nanosysid").read_text() == record
    else:
        assert not out.exists(), list(out.iterdir())


def test_a_stage_that_succeeds_keeps_no_earlier_version(tmp_path, params):
    out = tmp_path / "scores.json"

    def main(cfg):
        with dataio.atomic_file(out) as tmp:
            tmp.write_text("{}")

    main.__module__ = "stages.faulty"
    for _ in range(2):
        assert run_stage(main, description="", argv=["--params", str(params)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == [".scores.json.nanosysid", "scores.json"]


def test_an_output_that_cannot_be_moved_aside_is_left_as_it_was_with_nothing_beside_it(tmp_path, monkeypatch):
    # an immutable folder (chattr +i): the old output cannot be moved aside for the new one
    out = tmp_path / "split"
    with dataio.atomic_dir(out) as tmp:
        (tmp / "a.csv").write_text("old")
    real_replace = os.replace

    def refuse_moving_out(src, dst):
        if Path(src) == out:
            raise OSError(errno.EPERM, "Operation not permitted", str(src))
        return real_replace(src, dst)

    monkeypatch.setattr(dataio.os, "replace", refuse_moving_out)
    with pytest.raises(OSError):
        with dataio.atomic_dir(out) as tmp:
            (tmp / "a.csv").write_text("new")
    assert (out / "a.csv").read_text() == "old"
    assert [p.name for p in tmp_path.iterdir() if p.name != "split" and not p.name.endswith(".nanosysid")] == []


@pytest.mark.parametrize("in_a_stage", [False, True], ids=["from Python", "in a stage"])
def test_a_new_folder_that_cannot_be_put_in_place_leaves_the_old_one_there(tmp_path, monkeypatch, params, capsys,
                                                                          in_a_stage):
    out = tmp_path / "split"
    with dataio.atomic_dir(out) as tmp:
        (tmp / "a.csv").write_text("old")
    real_replace = os.replace

    def refuse_the_new_one(src, dst):
        if Path(dst) == out and Path(src).name.endswith(".tmp"):
            raise OSError(errno.EIO, "Input/output error", str(dst))
        return real_replace(src, dst)

    def main(cfg=None):
        monkeypatch.setattr(dataio.os, "replace", refuse_the_new_one)
        with dataio.atomic_dir(out) as tmp:
            (tmp / "a.csv").write_text("new")

    if in_a_stage:
        main.__module__ = "stages.faulty"
        assert run_stage(main, description="", argv=["--params", str(params)]) == 2
    else:
        with pytest.raises(OSError):
            main()
    assert (out / "a.csv").read_text() == "old"
    assert [p.name for p in tmp_path.iterdir() if p.name != "split" and not p.name.endswith(".nanosysid")] == []
