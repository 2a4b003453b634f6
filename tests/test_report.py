"""Report tables, figure signals and the predictions they draw: known answers."""

import json

import numpy as np
import pytest
import torch

from nanosysid import benchmark, models, so3, synthetic
from nanosysid.report import tables as report
from nanosysid.viz.signals import ahead, euler_deg


def scores(level, H=50):
    return benchmark.Scores(mae={k: np.full(H, level) for k in "pvRw"}, n_windows=1)


def test_results_table_bolds_the_best_model_not_the_oracle():
    text = report.results_table_md({"a": scores(2.0), "b": scores(1.0), "oracle": scores(0.5)})
    row = {line.split("|")[1].strip(): line for line in text.splitlines()[2:]}
    assert "**1.0000**" in row["b"] and "**" not in row["a"] and "**" not in row["oracle (physical limit)"]
    assert row["b"].count("**") == 2 * 16  # every column


def test_latex_table_has_the_same_cells_and_bold():
    rows = {"a": scores(2.0), "b": scores(1.0), "oracle": scores(0.5)}
    tex = report.results_table_tex(rows)
    body = {line.split(" & ")[0]: line for line in tex.splitlines() if line.endswith(r"\\") and " & " in line}
    assert body["b"].count(r"\textbf{") == 16 and r"\textbf" not in body["a"]
    assert r"\textbf" not in body["oracle (physical limit)"]
    assert r"\textit{\textbf{50.0000}}" not in tex and r"\textbf{\textit{50.0000}}" in tex  # SimErr of b: 50 x 1.0
    assert tex.count(r"\multicolumn{4}") == 4


def test_cost_table_shows_microcontroller_columns_only_when_measured(tmp_path):
    for name, cost in {"physics": {"params": None, "flops": None}, "lstm": {"params": 25104, "flops": 40176}}.items():
        (tmp_path / "eval" / name).mkdir(parents=True)
        (tmp_path / "eval" / name / "metrics.json").write_text(json.dumps({"cost": cost}))
    costs = report.load_costs(tmp_path / "eval", ["physics", "lstm"], tmp_path / "export")
    text = report.cost_table_md(costs)
    assert "Instructions" not in text
    assert "| lstm | 25.1 | 40.2 | 2.09 |" in text and "| physics | – | – | 1.79 |" in text
    (tmp_path / "export").mkdir()
    (tmp_path / "export" / "lstm.json").write_text(json.dumps(
        {"instructions": 61234, "t_est_ms": 0.3646, "flash_kb": 101.2, "ram_kb": 1.5, "flops": 40000}))
    text = report.cost_table_md(report.load_costs(tmp_path / "eval", ["physics", "lstm"], tmp_path / "export"))
    assert "| lstm | 25.1 | 40.2 | 61,234 | 0.365 | 101.2 | 1.5 | 2.09 |" in text
    assert "| physics | – | – | – | – | – | – | 1.79 |" in text


def test_mae_csv_is_one_row_per_model_and_horizon():
    rows = {"a": scores(2.0, H=3), "b": scores(1.0, H=3)}
    rows["b"].mae["v"] = np.array([0.1, 0.2, 0.3])
    lines = report.mae_csv(rows).splitlines()
    assert lines[0] == "h,model,p,v,R,w" and len(lines) == 7
    assert lines[5] == "2,b,1,0.2,1,1"


def test_ahead_places_each_prediction_h_samples_after_its_start():
    flight = synthetic.synthetic_flights(["melon_s_run1"], 80, seed=1)[0]
    H = 10
    pred = benchmark.predictions(models.predictor("physics"), flight, horizon=H)
    assert pred.shape == (70, H, 13)
    a = ahead(pred, H, len(flight))
    assert np.isnan(a[:H]).all() and np.isnan(a[H + 70:]).all()
    assert np.array_equal(a[H + 5], pred[5, H - 1])
    # a subset of starts is the same rollout as the full set
    sub = benchmark.predictions(models.predictor("physics"), flight, horizon=H, starts=np.array([5, 30]))
    assert np.allclose(sub, pred[[5, 30]])
    b = ahead(sub, H, len(flight), starts=np.array([5, 30]))
    assert np.allclose(b[[H + 5, H + 30]], a[[H + 5, H + 30]]) and np.isnan(b).all(axis=1).sum() == len(flight) - 2


def test_euler_angles_of_known_rotations():
    angles = np.radians([[30.0, 0.0, 0.0], [0.0, -20.0, 0.0], [0.0, 0.0, 100.0], [10.0, 20.0, 30.0]])
    # q = yaw * pitch * roll (ZYX)
    axes = torch.eye(3, dtype=torch.float64)
    q = []
    for r, p, y in angles:
        qr, qp, qy = (so3.quat_exp(torch.tensor(a) * axes[i]) for i, a in enumerate((r, p, y)))
        q.append(so3.quat_mul(qy, so3.quat_mul(qp, qr)).numpy())
    assert euler_deg(np.array(q)) == pytest.approx(np.degrees(angles), abs=1e-9)
