"""Each stage on a tiny case in a temporary folder (the pipeline under DVC: test_dvc.py)."""

import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml

from nanosysid import config
from nanosysid.dataio import read_flight_csv
from nanosysid.errors import DataError
from nanosysid.vehicle import Vehicle
from nanosysid.discover import VERDICTS as discover_verdicts
from nanosysid.discover.rules import violations
from nanosysid.effects import LIBRARY as discover_library
from stages import (compare, discover, evaluate, export, extract, filter as filter_stage, identify, mcu, quality, report,
                    simulate, split, sync, train, visualize)
from stages.common import run_stage

ROOT = Path(__file__).resolve().parents[1]

# two short simulated flights: enough for every stage, seconds to run
TINY_SIM = [
    "sim.runs={square: 0, random: 0, chirp: 2, melon: 2, yawsweep: 1}",
    "sim.flight.preroll=0.5",
    # the full throttle of a fresh cell: a Melon of 3 s and a Chirp of 6 s ask the rotors for more
    # than the rig's 2500 rad/s, and held there a flight's own motor lag moves by 20 ms
    "sim.flight.omega_max=2900",
    # the simulator's and the oracle's eager step, as the quick profile's (the compiled ones are
    # checked against them in tests/test_sim.py, and run in tests/test_numerics.py)
    "sim.flight.compile=false",
    "sim.flight.trajectories.yawsweep.duration=4.0",
    "sim.flight.trajectories.yawsweep.fade=0.5",
    "sim.flight.trajectories.chirp.duration=6.0",
    "sim.flight.trajectories.melon={duration: 3.0, circle_time: 2.0, return_time: 0.5}",
    # one noise level: a Melon of 3 s moves its rotors many times harder than any of the rig's
    # flights, and the sensors' vibration would grow with it far past the rig's
    "sim.flight.noise.vibration_ref=0",
    "export.mcu.start=10",
    "export.mcu.steps=20",
    # blocks longer than the horizon: discovery scores its choices on windows inside one block
    "discover.block=0.6",
    "visualize.stride=40",
    # every learned model: two epochs, and the eager physics base (compiling it costs more than
    # two epochs of it; the compiled one is checked against it in tests/test_learned.py)
    "trainer.every_model={epochs: 2, stride: 10, val_runs: [2], compile: false}",
]
LEARNED = ("residual", "phys_res", "lstm")
# the product's models: a user's own in conf/model/ (the README's steps) are no part of this pipeline
MODELS = ("naive", "physics", "physics_full", "oracle", *LEARNED, "discovered")


def _product_models(params: Path) -> None:
    """``params`` without models other than the product's (and their training and export)."""
    cfg = yaml.safe_load(params.read_text())
    for block in (cfg["models"], cfg["learned"], cfg["export"]["models"]):
        for name in [n for n in block if n not in MODELS]:
            del block[name]
    params.write_text(yaml.safe_dump(cfg, sort_keys=False))


def tiny_args(root: Path, *extra: str) -> list[str]:
    """Stage arguments that put every input and output of the pipeline under ``root`` (the
    settings derived from these, the identified ``params.json`` of every model, follow them)."""
    params = root / "params.yaml"
    if not params.exists():
        config.compose([], out=params, conf_dir=ROOT / "conf")
        _product_models(params)
    return [
        "--params", str(params),
        f"sim.out_dir={root / 'raw'}",
        f"preprocess.bags_dir={root / 'raw' / 'bags'}",
        f"preprocess.extract_dir={root / 'extract'}",
        f"preprocess.sync_dir={root / 'sync'}",
        f"preprocess.flights_dir={root / 'flights'}",
        f"preprocess.report_dir={root / 'reports'}",
        f"data.flights_dir={root / 'flights'}",
        f"paths.split={root / 'split'}",
        f"paths.eval={root / 'eval'}",
        f"paths.sim_report={root / 'sim'}",
        f"identify.out_dir={root / 'physics'}",
        f"paths.train_logs={root / 'train'}",
        f"report.markdown={root / 'report' / 'benchmark.md'}",
        f"report.latex={root / 'report' / 'benchmark.tex'}",
        f"report.figures={root / 'report' / 'figures'}",
        f"report.plots={root / 'report' / 'mae.csv'}",
        f"report.summary={root / 'report' / 'summary.json'}",
        "report.lineplot.window=[0.5,2.5]",
        f"visualize.out_dir={root / 'rerun'}",
        f"export.out_dir={root / 'models'}",
        f"paths.export={root / 'export'}",
        f"discover.out_dir={root / 'discovered'}",
        f"discover.report_dir={root / 'discovery'}",
        *(f"models.{m}.checkpoint={root / 'models' / m / 'model.pt'}" for m in LEARNED),
        *TINY_SIM,
        *extra,
    ]


def run(stage, root, *extra, name=None):
    args = tiny_args(root, *extra)
    if name is None:
        return run_stage(stage.main, description="", argv=args)
    return run_stage(stage.main, description="", name_arg="model", argv=[name, *args])


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    root = tmp_path_factory.mktemp("pipeline")
    for stage in (simulate, extract, sync, filter_stage, quality, split, identify):
        assert run(stage, root) == 0, stage.__name__
    for m in LEARNED:
        assert run(train, root, name=m) == 0, m
    return root


def test_simulate_records_bags_truth_and_direct_csvs(tiny):
    raw = tiny / "raw"
    assert sorted(p.name for p in (raw / "bags").iterdir()) == sorted(
        f"{n}{s}" for n in ("chirp_20250601_run1", "chirp_20250601_run2", "melon_20250601_run1", "melon_20250601_run2",
                            "yawsweep_20250601_run1")
        for s in ("", ".truth.json", ".truth.parquet"))
    csvs = sorted(str(p.relative_to(raw / "csv")) for p in (raw / "csv").rglob("*.csv"))
    assert csvs == ["chirp_20250601_run1.csv", "chirp_20250601_run2.csv", "melon_20250601_run1.csv",
                    "melon_20250601_run2.csv", "yawsweep_20250601_run1.csv"]


def test_processed_flights_match_the_truth(tiny):
    flights = sorted(p.stem for p in (tiny / "flights").glob("*.csv"))
    assert flights == ["chirp_20250601_run1", "chirp_20250601_run2", "melon_20250601_run1", "melon_20250601_run2",
                       "yawsweep_20250601_run1"]
    # the calibration flight keeps its yaw setpoint, which the benchmark's flights have no column for
    cal = read_flight_csv(tiny / "flights" / "yawsweep_20250601_run1.csv")
    assert np.abs(cal.extra["yaw_ref"]).max() > 0.1 and "yaw_ref" not in read_flight_csv(
        tiny / "flights" / "melon_20250601_run1.csv").extra
    assert len(read_flight_csv(tiny / "flights" / "melon_20250601_run1.csv")) in range(299, 303)
    q = json.loads((tiny / "reports" / "quality.json").read_text())
    for row in q["flights"]:
        assert row["pos_rms_mm"] < 5 and row["att_rms_rad"] < 0.01 and row["rotor_rms_pct_hover"] < 2
        assert abs(row["motor_lag_ms"] - row["motor_lag_injected_ms"]) < 10
    assert "| melon_20250601_run2 |" in (tiny / "reports" / "quality.md").read_text()
    assert "| chirp_20250601_run1 |" in (tiny / "reports" / "sync.md").read_text()


@pytest.mark.parametrize("field", ["motor_lag", "motor_lag_flight"])
def test_quality_fails_when_a_flights_motor_lag_is_20_ms_off(tiny, tmp_path, field):
    # the applied lag 20 ms off the injected one, or a flight's own estimate 20 ms off its session's
    reports = json.loads((tiny / "reports" / "sync.json").read_text())
    bad = reports[1]
    bad[field] = bad["motor_lag"] + 0.020
    (tmp_path / "sync.json").write_text(json.dumps(reports))
    with pytest.raises(DataError, match=re.escape(bad["flight"])) as e:
        quality.quality_report(tiny / "flights", tiny / "raw" / "bags", tiny / "raw" / "csv", tmp_path / "sync.json",
                               tmp_path, vehicle=Vehicle(), test_trajectories=["melon"], horizon=10)
    assert "10 ms" in str(e.value) and "preprocess.sync.lag_tolerance" in str(e.value)
    assert {p.split(":")[0] for p in json.loads((tmp_path / "quality.json").read_text())["motor_lag_problems"]} == {
        bad["flight"]}


def test_identify_writes_coefficients_and_figure(tiny):
    fit = json.loads((tiny / "physics" / "params.json").read_text())
    assert abs(fit["k_f"] / 3.72e-8 - 1) < 0.03 and fit["thrust_fit"]["r2"] > 0.9
    assert fit["train_flights"] == ["chirp_20250601_run1", "chirp_20250601_run2"]
    # the yaw calibration flight went through the recording chain with its setpoint: k_M by
    # instrumental variables, the paper's least squares beside it
    assert fit["calibration_flights"] == ["yawsweep_20250601_run1"]
    assert fit["yaw_fit"]["estimator"].startswith("instrumental variables")
    assert "least squares" in fit["yaw_fit_paper_method"]["estimator"]
    lo, hi = fit["thrust_fit"]["ci95"]
    assert lo < fit["k_f"] < hi


def test_identify_without_a_calibration_flight_names_its_estimator_and_the_bias_risk(tiny, tmp_path):
    # a user's CSVs (here the four benchmark flights for training): no flight with yaw excitation;
    # the two training flights alone leave k_M undetermined (its interval holds zero: refused)
    user = tmp_path / "user"
    for f in [*(tiny / "split").rglob("*.csv")]:
        (user / "train").mkdir(parents=True, exist_ok=True)
        shutil.copyfile(f, user / "train" / f.name)
    (user / "test").mkdir()
    shutil.copyfile(tiny / "flights" / "yawsweep_20250601_run1.csv", user / "test" / "yawsweep_20250601_run1.csv")
    assert run(identify, tiny, f"paths.split={user}", f"data.flights_dir={user / 'train'}",
               f"identify.out_dir={tmp_path}") == 0
    fit = json.loads((tmp_path / "params.json").read_text())
    assert fit["calibration_flights"] == [] and "yaw_fit_paper_method" not in fit
    assert "least squares" in fit["yaw_fit"]["estimator"] and fit["closed_loop_bias"].startswith("possible")
    assert fit["yaw_fit"]["ci95"] is not None
    assert (tiny / "physics" / "identify.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_split_and_evaluate(tiny):
    summary = json.loads((tiny / "split" / "split.json").read_text())
    assert list(summary["train"]["flights"]) == ["chirp_20250601_run1", "chirp_20250601_run2"]
    assert list(summary["test"]["flights"]) == ["melon_20250601_run1", "melon_20250601_run2"]
    simerr = {}
    for model in ("naive", "physics", "physics_full", "oracle", *LEARNED):
        assert run(evaluate, tiny, name=model) == 0
        m = json.loads((tiny / "eval" / model / "scores.json").read_text())
        n = summary["test"]["samples"] - 2 * 50
        assert m["n_windows"] == n and len(m["mae"]["p"]) == 50
        assert set(m["per_flight"]) == {"melon_20250601_run1", "melon_20250601_run2"}
        assert f"| {model}" in (tiny / "eval" / model / "table.md").read_text()
        simerr[model] = m["simerr"]
    assert simerr["physics"]["p"] < 0.3 * simerr["naive"]["p"]
    assert simerr["oracle"]["v"] < simerr["physics"]["v"]
    # two epochs on 3 s of flight teach little; phys_res cannot be worse than its physics start
    assert simerr["phys_res"]["p"] < 1.5 * simerr["physics"]["p"]


def test_every_stage_reads_the_identified_params_of_the_out_dir_it_is_given(tiny, caplog):
    # identify.out_dir is the tiny pipeline's: the physics model's k_F, k_M come from its file,
    # not from the repository's models/physics/params.json
    with caplog.at_level("INFO", logger="nanosysid.identify"):
        assert run(evaluate, tiny, name="physics") == 0
    read = [r.getMessage() for r in caplog.records if "from " in r.getMessage()]
    assert read and all(m.endswith(str(tiny / "physics" / "params.json")) for m in read), read


def evaluated(tiny):
    if not (tiny / "discovered" / "model.json").exists():
        assert run(discover, tiny) == 0
    for model in ("naive", "physics", "physics_full", "oracle", *LEARNED, "discovered"):
        if not (tiny / "eval" / model / "metrics.json").exists():
            assert run(evaluate, tiny, name=model) == 0
    return tiny


def md_table(text, heading):
    """Rows of the first Markdown table after ``heading``: {first cell: [other cells]}."""
    lines = text[text.index(heading):].splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("|"))
    rows = {}
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in line.strip("|").split("|")]
        rows[cells[0]] = cells[1:]
    return rows


def md_header(text, heading):
    """The header cells of the first Markdown table after ``heading``."""
    line = next(x for x in text[text.index(heading):].splitlines() if x.startswith("|"))
    return [c.strip() for c in line.strip("|").split("|")]


def test_report_shows_every_model_with_its_evaluated_numbers(tiny):
    tiny = evaluated(tiny)
    assert run(report, tiny) == 0
    text = (tiny / "report" / "benchmark.md").read_text()
    rows = md_table(text, "## Multi-step prediction")
    assert set(rows) == {"naive", "physics", "physics_full", "oracle (physical limit)", *LEARNED, "discovered"}
    for label, cells in rows.items():
        m = json.loads((tiny / "eval" / label.split()[0] / "metrics.json").read_text())
        expected = [v for k in ("p", "v", "R", "w") for v in (m["h1"][k], m["h10"][k], m["h50"][k], m["simerr"][k])]
        assert [float(c.strip("*")) for c in cells] == pytest.approx(expected, abs=5e-5)
    assert any("**" in c for c in rows["physics"] + rows["phys_res"] + rows["naive"])
    assert not any(c.startswith("**") for c in rows["oracle (physical limit)"])
    # the discovered row says which rows it is read against, so its gap to the paper's physics row reads right
    assert "read it against the better of `physics` and `physics_full` in each quantity" in text
    costs = md_table(text, "## Cost of one step")
    for m in LEARNED:
        summary = json.loads((tiny / "train" / m / "summary.json").read_text())
        assert float(costs[m][0]) == pytest.approx(summary["params"] / 1e3, abs=0.05)
        # about 2 FLOPs per weight used in a step (the LSTM's initialisation network is not)
        assert 1.5 < float(costs[m][1]) / (summary["params"] / 1e3) < 2.1
    # the paper's Table (Cost) gives T_inf = 1.79 ms for the physics model, whichever columns
    # the MCU runs have added before it
    paper = md_header(text, "## Cost of one step").index("Paper T_inf [ms]")
    assert costs["naive"][0] == "–" and costs["physics"][paper - 1] == "1.79" and costs["lstm"][paper - 1] == "2.09"
    tex = (tiny / "report" / "benchmark.tex").read_text()
    assert tex.count(r"\begin{tabular}") == 2 and r"oracle (physical limit)" in tex and r"\textbf{" in tex
    for fig in ("mae_horizon", "predictions", "trajectories"):
        assert f"(figures/{fig}.png)" in text
        assert (tiny / "report" / "figures" / f"{fig}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    curves = (tiny / "report" / "mae.csv").read_text().splitlines()
    assert curves[0] == "h,model,p,v,R,w" and len(curves) == 1 + 8 * 50
    # a reversed window of the prediction figure is refused before any output is replaced
    before = (tiny / "report" / "benchmark.md").read_bytes()
    assert run(report, tiny, "report.lineplot.window=[2.5,0.5]") == 2
    assert (tiny / "report" / "benchmark.md").read_bytes() == before
    m = json.loads((tiny / "eval" / "lstm" / "scores.json").read_text())
    h10 = next(line for line in curves if line.startswith("10,lstm,")).split(",")
    assert float(h10[4]) == pytest.approx(m["mae"]["R"][9], rel=1e-6)
    # the metrics experiments are compared on: each model's SimErr, as its evaluation has it
    summary = json.loads((tiny / "report" / "summary.json").read_text())["simerr"]
    for label in rows:
        name = label.split()[0]
        evaluated_simerr = json.loads((tiny / "eval" / name / "metrics.json").read_text())["simerr"]
        assert summary[name] == pytest.approx(evaluated_simerr, rel=1e-12), name


def test_compare_sets_the_dataset_beside_the_paper(tiny):
    tiny = evaluated(tiny)
    assert run(compare, tiny, "sim.effects.inertia_offset=0.5") == 0
    text = (tiny / "sim" / "stats.md").read_text()
    world = md_table(text, "## The simulated world")
    assert world["`inertia_offset`"][:2] == ["0.5", "0"] and world["`turbulence`"][:2] == ["1", "1"]
    assert "| melon | 2.99 / 65.00 (0.05 ✗)" in text  # the processed flight: 300 samples
    ratios = md_table(text, "## The pattern of the results")
    simerr = {m: json.loads((tiny / "eval" / m / "metrics.json").read_text())["simerr"] for m in LEARNED + ("physics",)}
    for m in LEARNED:
        assert [float(c.split()[0]) for c in ratios[f"{m} / physics, ours"]] == pytest.approx(
            [simerr[m][k] / simerr["physics"][k] for k in "pvRw"], abs=5e-3)
        assert ratios[f"{m} / physics, paper"][0] == {"residual": "1.74", "phys_res": "1.02", "lstm": "2.57"}[m]
    record = json.loads((tiny / "sim" / "stats.json").read_text())
    # the naive and physics rows, each learned model's ratios, the best of each column, and three
    # of the identification (the paper's k_M by its method, k_F and k_M against nature's)
    assert set(record["best"]) == set("pvRw") and len(record["checks"]) == 1 + len(LEARNED) + 1 + 3
    assert [c for c in record["checks"] if "within 25% of the paper's ratio" in c] == [
        f"{m} / physics within 25% of the paper's ratio" for m in ("residual", "phys_res", "lstm")]
    # the identification beside nature's coefficients and the paper's k_M
    ident = record["identification"]
    fit = json.loads((tiny / "physics" / "params.json").read_text())
    assert ident["k_m"]["identified"] == fit["k_m"] and ident["k_m"]["paper"] == 7.73e-11
    assert ident["k_m"]["paper_method"] == fit["yaw_fit_paper_method"]["coef"]
    assert "| k_M, the paper's method |" in text.split("## Identification against nature")[1].split("\n## ")[0]
    naive_p10 = next(r for r in record["rows"] if r["model"] == "naive" and r["quantity"] == "p" and r["h"] == 10)
    assert naive_p10["paper"] == 0.1430


@pytest.mark.parametrize("model", ["physics", "lstm", "discovered"])
def test_export_and_mcu_stages(tiny, model):
    from nanosysid.errors import ToolchainError
    from nanosysid.export.mcu import require_toolchain

    if model == "discovered":
        evaluated(tiny)
    assert run(export, tiny, name=model) == 0
    out = tiny / "models" / model / "export"
    summary = json.loads((out / "export.json").read_text())
    assert summary["onnx"]["max_abs_diff"] <= 1e-5 and summary["onnx"]["samples"] == 1000
    assert (out / "step.onnx").exists() and (out / "init.onnx").exists() == (model == "lstm")
    assert "void nsi_step(" in (out / "model.c").read_text()
    try:
        require_toolchain()
    except ToolchainError as e:
        pytest.skip(str(e))
    assert run(mcu, tiny, name=model) == 0
    result = json.loads((tiny / "export" / f"{model}.json").read_text())
    assert result["steps"] == 20 and result["max_rel_diff"] <= 1e-5
    # one step's instructions against its operation count, counted apart from the firmware: at
    # least one instruction per fused multiply-add, and not much more than one per operation
    # plus its loads (a count of the whole run, or of no step, would fall outside)
    evaluated(tiny)
    flops = json.loads((tiny / "eval" / model / "metrics.json").read_text())["cost"]["flops"]
    assert 0.5 * flops <= result["instructions"] <= 4 * flops, (result["instructions"], flops)
    assert (tiny / "models" / model / "mcu" / "firmware.elf").exists()


def test_the_mcu_stage_switched_off_needs_no_toolchain_and_records_no_figure(tiny, monkeypatch):
    import shutil

    monkeypatch.setattr(shutil, "which", lambda tool: None)  # no compiler, no QEMU on this machine
    assert run(mcu, tiny, "export.mcu.enabled=false", f"export.out_dir={tiny / 'mcu-off'}",
               f"paths.export={tiny / 'export-off'}", name="physics") == 0
    result = json.loads((tiny / "export-off" / "physics.json").read_text())
    assert result["model"] == "physics" and "enabled is false" in result["skipped"]
    assert "instructions" not in result
    assert (tiny / "mcu-off" / "physics" / "mcu" / "SKIPPED.txt").exists()
    assert run(mcu, tiny, f"export.out_dir={tiny / 'mcu-off'}", f"paths.export={tiny / 'export-off'}",
               name="physics") != 0  # switched on, the missing toolchain is the stage's error


def test_a_discovered_model_of_the_rotors_history_is_recorded_as_not_exported(tiny):
    from nanosysid.discover.model import save_discovered
    from nanosysid.vehicle import Vehicle

    model = tiny / "slow" / "model.json"
    save_discovered(model, Vehicle(), {"slow_actuation": {"coefficients": [0.0, 0.2, 0.0]},
                                       "induced_drag": {"coefficients": [1e-6, 1e-6]}}, 0.0)
    where = (f"models.discovered.model={model}", f"export.out_dir={tiny / 'slow-models'}",
             f"paths.export={tiny / 'slow-export'}")
    assert run(export, tiny, *where, name="discovered") == 0  # the pipeline goes on
    summary = json.loads((tiny / "slow-models" / "discovered" / "export" / "export.json").read_text())
    assert summary["exportable"] is False and "slow_actuation" in summary["reason"]
    assert "induced_drag" not in summary["reason"]  # it names the effect that stops it, not every one
    assert not (tiny / "slow-models" / "discovered" / "export" / "model.c").exists()
    assert run(mcu, tiny, *where, name="discovered") == 0
    result = json.loads((tiny / "slow-export" / "discovered.json").read_text())
    assert "not exported" in result["skipped"] and "instructions" not in result


def test_discover_stage_writes_the_augmented_model_and_its_report(tiny):
    tiny = evaluated(tiny)
    model = json.loads((tiny / "discovered" / "model.json").read_text())
    result = json.loads((tiny / "discovery" / "result.json").read_text())
    assert model["format"] == "nanosysid-discovered-1"
    # the model applies the named, ambiguous and undetermined findings' entries (not an unstable
    # one), and every verdict obeys the rules of docs/discovery.md
    used = [f["name"] or f["alternatives"][0] for f in result["findings"]
            if f["verdict"] in ("named", "ambiguous", "undetermined")]
    wrench = [n for n in used if discover_library[n].kind == "wrench"]
    assert [n for n in model["effects"] if not n.startswith("term:")] == wrench
    assert all(f["verdict"] in discover_verdicts for f in result["findings"])
    assert violations(result) == []
    # beside the oracle, the limit of a model of the state (the oracle without the effects of time),
    # integrated and with ω held
    assert set(result["simerr"]) == {"nominal", "physics", "best_nominal", "discovered", "oracle", "state_limit",
                                     "held_state_limit", "sindy"}
    assert set(result["gap_closed_state_limit"]) == set("pvRw") == set(result["gap_closed_held_state_limit"])
    scores = json.loads((tiny / "eval" / "discovered" / "scores.json").read_text())
    assert scores["simerr"] == pytest.approx(result["simerr"]["discovered"])
    # the nominal model of discovery is the full physics model (rotor torques integrated) that
    # the evaluate stage scores, and its held-rate twin the paper's physics model
    physics = json.loads((tiny / "eval" / "physics_full" / "scores.json").read_text())
    assert result["simerr"]["nominal"] == pytest.approx(physics["simerr"], rel=1e-9)
    held = json.loads((tiny / "eval" / "physics" / "scores.json").read_text())
    assert result["simerr"]["physics"] == pytest.approx(held["simerr"], rel=1e-9)
    # held, the true dynamics predict each window's first angular velocity throughout, as physics
    # does: the same ω error, and the attitude turned at that rate alike
    limit = result["simerr"]["held_state_limit"]
    assert limit["w"] == pytest.approx(held["simerr"]["w"], rel=1e-9)
    assert limit["R"] == pytest.approx(held["simerr"]["R"], rel=1e-3)
    assert result["simerr"]["best_nominal"] == pytest.approx(
        {q: min(physics["simerr"][q], held["simerr"][q]) for q in "pvRw"}, rel=1e-12)
    # the model integrates the torque equation about the axes the base section chose, and the
    # generated model holds them: every row of that section is a held-out rollout of the training
    # flights, and the axes chosen are among those tried
    assert model["integrated"] == result["base"]["integrated"]
    assert result["base"]["integrated"] in {r["integrated"] for r in result["base"]["rows"]}
    assert "## The model's base, axis by axis" in (tiny / "discovery" / "report.md").read_text()
    oracle = json.loads((tiny / "eval" / "oracle" / "scores.json").read_text())
    assert result["simerr"]["oracle"] == pytest.approx(oracle["simerr"], rel=1e-9)
    # each named effect is in the report with the coefficients of the result
    text = (tiny / "discovery" / "report.md").read_text()
    assert "## Verdicts" in text
    # and it says which k_M its nominal model started from: the identify stage's estimator
    ident = json.loads((tiny / "physics" / "params.json").read_text())
    assert f"k_M by {ident['yaw_fit']['estimator']}" in text
    # one k_F and one k_M: the identify stage's, in the model and in its report
    assert model["vehicle"]["k_f"] == ident["k_f"] and model["vehicle"]["k_m"] == ident["k_m"]
    assert result["k_m"]["given"] == ident["k_m"]
    assert f"identify stage's ({ident['k_f']:.4g} N s²/rad² and {ident['k_m']:.4g} N m s²/rad²)" in text
    for f in result["findings"]:
        if f["verdict"] == "named":
            assert f"`{f['name']}` named" in text
            for param, value in f["params"].items():
                shown = re.search(rf"\| {re.escape(param)} \| ([-+0-9.e]+) \|", text)
                assert shown and float(shown.group(1)) == pytest.approx(value, rel=5e-3), param


def test_visualize_writes_a_recording_per_test_flight(tiny):
    import rerun.chunk as rc

    evaluated(tiny)
    # the recordings show the rollouts the evaluate stage kept: no model is loaded or rolled out
    # again, so they are written with every model's artifact out of reach
    away = tiny / "away"
    away.mkdir(exist_ok=True)
    for m in LEARNED:
        (tiny / "models" / m / "model.pt").rename(away / f"{m}.pt")
    try:
        assert run(visualize, tiny) == 0
    finally:
        for m in LEARNED:
            (away / f"{m}.pt").rename(tiny / "models" / m / "model.pt")
    files = sorted(p.name for p in (tiny / "rerun").iterdir() if not p.name.startswith("."))
    assert files == ["melon_20250601_run1.rrd", "melon_20250601_run2.rrd"]
    T = len(read_flight_csv(tiny / "split" / "test" / "melon_20250601_run1.csv"))
    n = T - 50
    S = len(range(0, n, 40))
    store = rc.RrdReader(tiny / "rerun" / files[0]).store().stream().collect()
    rows = {}
    for chunk in store.stream():
        if not chunk.is_static:
            rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    models = ("naive", "physics", "physics_full", "oracle", *LEARNED, "discovered")
    expected = {"/world/drone": T, "/world/rollouts/truth": S}
    for m in models:
        expected[f"/world/rollouts/{m}"] = S
        for q in ("p", "v", "R", "w"):
            expected[f"/signals/{q}/{m}"] = n
            expected[f"/errors/{q}/{m}"] = n
    for q in ("p", "v", "R", "w"):
        expected[f"/signals/{q}/truth"] = T
    assert rows == expected


def test_training_logs_every_epoch_with_dvclive(tiny):
    for m in LEARNED:
        summary = json.loads((tiny / "train" / m / "summary.json").read_text())
        assert summary["params"] > 15_000 and summary["epochs"] == 2
        rows = (tiny / "train" / m / "plots" / "metrics" / "val" / "loss.tsv").read_text().splitlines()
        assert rows[0].split("\t") == ["step", "loss"] and len(rows) == 3  # header + 2 epochs, no time stamps


def test_failing_split_keeps_previous_output_and_names_the_file(tiny, tmp_path, capsys):
    work = tmp_path / "w"
    shutil.copytree(tiny, work, ignore=shutil.ignore_patterns("params.yaml"))
    before = sorted(p.relative_to(work) for p in (work / "split").rglob("*"))
    bad = work / "flights" / "melon_20250601_run2.csv"
    bad.write_text(bad.read_text().replace("\n", "\n,,,\n", 1))
    assert run(split, work) == 2
    err = capsys.readouterr().err
    assert err.count("error:") == 1 and str(bad) in err and "column 't', row 0" in err
    assert sorted(p.relative_to(work) for p in (work / "split").rglob("*")) == before
    # no temporary left beside it (the outputs' records are the guard's)
    assert not [p for p in work.iterdir() if p.name.startswith(".") and not p.name.endswith(".nanosysid")]


def test_stage_runs_as_a_module_with_overrides(tiny, tmp_path, venv_env):
    args = tiny_args(tiny, f"paths.eval={tmp_path / 'eval'}", "eval.horizon=10")
    r = subprocess.run(["python", "-m", "stages.evaluate", "naive", *args], cwd=ROOT, env=venv_env,
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    m = json.loads((tmp_path / "eval" / "naive" / "scores.json").read_text())
    assert m["horizon"] == 10


def test_unknown_model_is_one_clear_error(tiny, capsys):
    assert run(evaluate, tiny, name="lstmx") == 2
    assert "models.lstmx: no such model" in capsys.readouterr().err


@pytest.mark.parametrize("stage, key, onto", [
    (extract, "preprocess.extract_dir", "raw/bags"),   # the output folder is the bags folder
    (split, "paths.split", "flights"),                # the split written over the flights it splits
    (sync, "preprocess.sync_dir", "reports"),          # a folder the stage did not write
])
def test_a_stage_never_replaces_its_input_or_a_folder_it_did_not_write(tiny, tmp_path, capsys, stage, key, onto):
    work = tmp_path / "w"
    shutil.copytree(tiny, work, ignore=shutil.ignore_patterns("rerun", "models", "train"))
    before = sorted(str(p.relative_to(work)) for p in work.rglob("*"))
    assert run(stage, work, f"{key}={work / onto}") == 2
    err = capsys.readouterr().err
    assert err.count("error:") == 1 and str(work / onto) in err
    assert sorted(str(p.relative_to(work)) for p in work.rglob("*")) == before


def test_an_interrupted_training_or_evaluation_keeps_the_previous_outputs_whole(tiny, tmp_path, monkeypatch):
    work = tmp_path / "w"
    shutil.copytree(tiny, work, ignore=shutil.ignore_patterns("params.yaml", "rerun"))
    if not (work / "eval" / "physics" / "scores.json").exists():
        assert run(evaluate, work, name="physics") == 0

    def snapshot(folder):
        return {str(p.relative_to(work)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}

    logs, ckpt, scores = work / "train" / "residual", work / "models" / "residual", work / "eval" / "physics"
    before = snapshot(logs), snapshot(ckpt), snapshot(scores)

    def killed_training(*args, log_dir, **kw):
        # dvclive has written the first epoch of the new run when the run is killed
        (log_dir / "metrics.json").write_text('{"train": {"loss": 1.0}}')
        raise KeyboardInterrupt

    monkeypatch.setattr(train, "train_model", killed_training)
    with pytest.raises(KeyboardInterrupt):
        run(train, work, name="residual")

    def killed_table(*args, **kw):
        raise KeyboardInterrupt

    monkeypatch.setattr(evaluate, "results_table_md", killed_table)
    with pytest.raises(KeyboardInterrupt):
        run(evaluate, work, "eval.horizon=20", name="physics")  # scores.json would change
    assert (snapshot(logs), snapshot(ckpt), snapshot(scores)) == before
    assert not [p for p in work.rglob(".*.tmp")]
