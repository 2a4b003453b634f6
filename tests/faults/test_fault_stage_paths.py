"""A stage whose settings point an output at its own input, at another stage's output or at the
project's code fails before it reads anything: one line naming the path and the setting, exit
code 2, and every file where it was."""

from __future__ import annotations

from pathlib import Path

import pytest

from stages import (compare, discover, evaluate, extract, filter as filter_stage, identify, quality, report, simulate,
                    split, sync, train, visualize)
from stages.common import run_stage

ROOT = Path(__file__).resolve().parents[2]

# every path the pipeline reads or writes, under the test's folder
PATHS = {
    "sim.out_dir": "raw", "preprocess.bags_dir": "raw/bags", "preprocess.extract_dir": "extract",
    "preprocess.sync_dir": "sync", "preprocess.flights_dir": "flights", "preprocess.report_dir": "reports",
    "data.flights_dir": "flights", "paths.split": "split", "paths.eval": "eval", "paths.sim_report": "sim",
    "identify.out_dir": "physics", "paths.train_logs": "train", "report.markdown": "report/benchmark.md",
    "report.latex": "report/benchmark.tex", "report.figures": "report/figures", "report.plots": "report/mae.csv",
    "visualize.out_dir": "rerun", "export.out_dir": "models", "paths.export": "export",
    "discover.out_dir": "discovered", "discover.report_dir": "discovery",
}

SMALL = ["sim.runs={square: 0, random: 0, chirp: 1, melon: 1, yawsweep: 0}", "sim.flight.preroll=0.5",
         "sim.flight.trajectories.chirp.duration=1.0",
         "sim.flight.trajectories.melon={duration: 1.0, circle_time: 0.5, return_time: 0.2}"]

CASES = [
    # (stage, its name argument, setting, value, the words)
    (extract, None, "preprocess.extract_dir", "sync", "the output of stage sync@sim"),
    (extract, None, "preprocess.extract_dir", "raw/bags", "the stage's input"),
    (extract, None, "preprocess.extract_dir", "raw/bags/x", "lies inside the stage's input"),
    (sync, None, "preprocess.sync_dir", "extract", "is the stage's input"),
    (sync, None, "preprocess.sync_dir", "flights", "the output of stage filter@sim"),
    (filter_stage, None, "preprocess.flights_dir", "sync", "is the stage's input"),
    (filter_stage, None, "preprocess.flights_dir", "split", "the output of stage split"),
    (quality, None, "preprocess.report_dir", "flights", "the stage's input"),
    (split, None, "paths.split", "flights", "is the stage's input"),
    (split, None, "paths.split", "flights/split", "lies inside the stage's input"),
    (split, None, "paths.split", "raw", "the output of stage simulate@sim"),
    (simulate, None, "sim.out_dir", "split", "the output of stage split"),
    (simulate, None, "sim.out_dir", "physics", "the output of stage identify"),
    (identify, None, "identify.out_dir", "split", "the stage's input"),
    (identify, None, "identify.out_dir", "raw/bags", "the output of stage simulate@sim"),
    (evaluate, "naive", "paths.eval", "split", "the stage's input"),
    (evaluate, "naive", "paths.eval", "physics/params.json", "the output of stage identify"),
    (train, "lstm", "paths.train_logs", "split/test", "the stage's input"),
    (train, "lstm", "paths.train_logs", "eval", "the output of stage evaluate"),
    (report, None, "report.plots", "split/test/melon_20250601_run1.csv", "the stage's input"),
    (report, None, "report.markdown", "eval/naive/table.md", "the stage's input"),
    (report, None, "report.figures", "eval", "the stage's input"),
    (compare, None, "paths.sim_report", "reports/quality.md", "lies inside"),
    (compare, None, "paths.sim_report", "split", "the stage's input"),
    (discover, None, "discover.report_dir", "split", "the stage's input"),
    (discover, None, "discover.out_dir", "physics/params.json", "lies inside"),
    (visualize, None, "visualize.out_dir", "split", "the stage's input"),
    (visualize, None, "visualize.out_dir", "discovery", "the stage's input"),
]

CLASS = "data loss"


@pytest.mark.parametrize("stage,name,setting,value,words", CASES,
                         ids=[f"{c[0].__name__.split('.')[-1]}: {c[2]}={c[3]}" for c in CASES])
def test_an_output_over_an_input_or_another_stages_output_fails_first(tmp_path, monkeypatch, capsys, params, stage,
                                                                      name, setting, value, words):
    monkeypatch.chdir(ROOT)  # dvc.yaml declares the stages' inputs and outputs
    (tmp_path / "flights").mkdir()
    (tmp_path / "flights" / "keep.txt").write_text("the user's")
    args = ["--params", str(params)] + [f"{k}={tmp_path / v}" for k, v in PATHS.items() if k != setting]
    args.append(f"{setting}={tmp_path / value}")
    args += SMALL  # should the guard miss, the stage's work is seconds
    before = sorted(str(p) for p in tmp_path.rglob("*"))
    code = run_stage(stage.main, description="", name_arg="model" if name else None,
                     argv=[name, *args] if name else args)
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.count("\n") == 0, err
    assert words in err and setting in err, err
    assert sorted(str(p) for p in tmp_path.rglob("*")) == before


def test_the_default_layout_has_no_output_over_an_input_or_another_output(params, monkeypatch):
    # the check every stage run makes, over the whole pipeline at once: the shipped settings pass
    from itertools import combinations

    from nanosysid import config, guard

    monkeypatch.chdir(ROOT)
    layout = guard.declared(config.load_params([], path=params))
    assert len(layout) > 20 and {"simulate@sim", "train@lstm", "evaluate@naive", "report"} <= set(layout)
    clashes = [(s, o, d) for s, (deps, outs) in layout.items() for o in outs for d in deps
               if guard._overlaps(guard._resolve(o), guard._resolve(d))]
    outs = [(s, o) for s, (_, os_) in layout.items() for o in os_]
    clashes += [(a, x, b, y) for (a, x), (b, y) in combinations(outs, 2)
                if a != b and guard._overlaps(guard._resolve(x), guard._resolve(y))]
    assert clashes == []
