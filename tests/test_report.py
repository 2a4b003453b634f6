"""Report tables, figure signals and the predictions they draw: known answers."""

import json

import numpy as np
import pytest
import torch

from nanosysid import predictors, protocol, so3, synthetic
from nanosysid.report import tables as report
from nanosysid.viz.signals import ahead, euler_deg


def scores(level, H=50):
    return protocol.Scores(mae={k: np.full(H, level) for k in "pvRw"}, n_windows=1)


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
        {"instructions": 61234, "t_est_ms": 0.3646, "t_max_ms": 6.927, "onnx_operators": 19, "flash_kb": 101.2,
         "ram_kb": 1.5, "flops": 40000}))
    text = report.cost_table_md(report.load_costs(tmp_path / "eval", ["physics", "lstm"], tmp_path / "export"))
    assert "| lstm | 25.1 | 40.2 | 61,234 | 0.365 | 6.927 | 19 | 101.2 | 1.5 | 2.09 |" in text
    assert "| physics | – | – | – | – | – | – | – | – | 1.79 |" in text


def test_the_papers_times_are_set_against_the_bounds_of_each_step():
    """At 168 MHz, 288 instructions take 1.71 µs at one cycle each and 32.6 µs at 19: the paper's
    1.79 ms for the physics step is 55 times the most; 61,234 instructions take 0.364 to 6.93 ms,
    which holds the LSTM's 2.09 ms; and the paper's phys_res is its physics plus its residual."""
    costs = {"physics": {"paper_t_inf_ms": 1.79, "t_est_ms": 288 / 168e3, "t_max_ms": 288 * 19 / 168e3,
                         "onnx_operators": 295},
             "residual": {"paper_t_inf_ms": 1.03, "t_est_ms": 0.426, "t_max_ms": 0.426 * 19},
             "phys_res": {"paper_t_inf_ms": 2.82, "t_est_ms": 0.429, "t_max_ms": 0.429 * 19},
             "lstm": {"paper_t_inf_ms": 2.09, "t_est_ms": 61234 / 168e3, "t_max_ms": 61234 * 19 / 168e3},
             "naive": {"paper_t_inf_ms": None}}
    text = "\n".join(report._paper_time_lines(costs))
    assert "`physics`: the paper's 1.79 ms is 55 times this step's most; its ONNX graph has 295 operators, 6.1 µs" in text
    assert "`lstm`: the paper's 2.09 ms lies within this step's bounds" in text
    assert "(1.79 + 1.03 = 2.82 ms)" in text and "naive" not in text


def test_mae_csv_is_one_row_per_model_and_horizon():
    rows = {"a": scores(2.0, H=3), "b": scores(1.0, H=3)}
    rows["b"].mae["v"] = np.array([0.1, 0.2, 0.3])
    lines = report.mae_csv(rows).splitlines()
    assert lines[0] == "h,model,p,v,R,w" and len(lines) == 7
    assert lines[5] == "2,b,1,0.2,1,1"


def test_ahead_places_each_prediction_h_samples_after_its_start():
    flight = synthetic.synthetic_flights(["melon_s_run1"], 80, seed=1)[0]
    H = 10
    pred = protocol.predictions(predictors.predictor("physics"), flight, horizon=H)
    assert pred.shape == (70, H, 13)
    a = ahead(pred, H, len(flight))
    assert np.isnan(a[:H]).all() and np.isnan(a[H + 70:]).all()
    assert np.array_equal(a[H + 5], pred[5, H - 1])
    # a subset of starts is the same rollout as the full set
    sub = protocol.predictions(predictors.predictor("physics"), flight, horizon=H, starts=np.array([5, 30]))
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


# ---- the dataset against the paper ------------------------------------------------------

# The paper's table of numerical performance, copied by hand: (h1, h10, h50, SimErr) per quantity.
PAPER = {
    "naive": {"p": (0.0143, 0.1430, 0.6797, 17.7878), "v": (0.0329, 0.3182, 1.4749, 38.9241),
              "R": (0.0071, 0.0692, 0.3041, 8.2138), "w": (0.0796, 0.3596, 0.8837, 29.0866)},
    "physics": {"p": (0.0013, 0.0126, 0.1269, 2.3223), "v": (0.0080, 0.0570, 0.5781, 10.6232),
                "R": (0.0011, 0.0205, 0.2544, 5.1013), "w": (0.0796, 0.3596, 0.8837, 29.0866)},
    "residual": {"p": (0.0032, 0.0305, 0.1712, 4.0519), "v": (0.0116, 0.0890, 0.5720, 12.5809),
                 "R": (0.0022, 0.0331, 0.2268, 6.0591), "w": (0.1138, 0.5949, 0.9005, 35.5735)},
    "phys_res": {"p": (0.0016, 0.0166, 0.1119, 2.3625), "v": (0.0092, 0.0613, 0.5556, 10.4033),
                 "R": (0.0027, 0.0376, 0.2306, 6.1534), "w": (0.0912, 0.4880, 0.5979, 28.9873)},
    "lstm": {"p": (0.0079, 0.0390, 0.2572, 5.9711), "v": (0.0247, 0.1175, 0.7407, 16.7207),
             "R": (0.0066, 0.0372, 0.2325, 5.6525), "w": (0.1021, 0.4292, 1.2407, 35.8353)},
}


def paper_like(model, scale=None):
    """Scores whose MAE at h = 1, 10, 50 and SimErr are the paper's (times ``scale[k]``)."""
    mae = {}
    for k, (h1, h10, h50, simerr) in PAPER[model].items():
        f = (scale or {}).get(k, 1.0)
        m = np.full(50, (simerr - h1 - h10 - h50) / 47)
        m[0], m[9], m[49] = h1, h10, h50
        mae[k] = m * f
    return protocol.Scores(mae=mae, n_windows=1)


def test_the_papers_own_results_meet_every_criterion():
    from nanosysid.report import paper

    c = paper.compare_results({m: paper_like(m) for m in PAPER})
    assert all(c.checks.values()) and len(c.checks) == 5  # the rows, three learned models' ratios, the best
    # Phys+Res over physics, worked by hand: 2.3625 / 2.3223, 10.4033 / 10.6232, 6.1534 / 5.1013,
    # 28.9873 / 29.0866
    for k, ratio in zip("pvRw", (1.01731, 0.97930, 1.20624, 0.99659)):
        ours, theirs = c.ratios[("phys_res", k)]
        assert ours == pytest.approx(ratio, abs=1e-5) and theirs == pytest.approx(ratio, abs=1e-5)
    # the paper's best of each SimErr column and its margin: R is physics by 5.6525 / 5.1013 - 1 = 10.8 %
    assert c.best["R"] == ("physics", "physics", pytest.approx(0.10805, abs=1e-4))
    assert c.best["p"][1] == "physics" and c.best["v"][1] == "phys_res" and c.best["w"][1] == "phys_res"


def test_a_pattern_unlike_the_papers_fails_its_criteria():
    from nanosysid.report import paper

    # a Phys+Res 30 % better on R than the paper's: its ratio 0.84 is 30 % off 1.21, and it is now the best on R
    rows = {m: paper_like(m) for m in PAPER}
    rows["phys_res"] = paper_like("phys_res", {"R": 0.7})
    c = paper.compare_results(rows)
    assert not c.checks["phys_res / physics within 25% of the paper's ratio"]
    assert c.best["R"][0] == "phys_res"
    assert not c.checks["best model of each SimErr column as the paper's where its margin is over 10%"]
    # an LSTM that beats physics on the angular velocity by 15 % (the paper's is 23 % worse): its
    # ratio 0.85 is 0.85 / (35.8353 / 29.0866) = 0.69 of the paper's, more than 25 % off
    rows = {m: paper_like(m) for m in PAPER}
    rows["lstm"] = paper_like("lstm", {"w": 0.85 * 29.0866 / 35.8353})
    c = paper.compare_results(rows)
    assert c.ratios[("lstm", "w")][0] == pytest.approx(0.85, abs=1e-4)
    assert not c.checks["lstm / physics within 25% of the paper's ratio"]
    assert c.checks["residual / physics within 25% of the paper's ratio"]
    # a physics row twice the paper's at every horizon is outside x1.5; the ratios move with it
    rows = {m: paper_like(m) for m in PAPER}
    rows["physics"] = paper_like("physics", {k: 2.0 for k in "pvRw"})
    c = paper.compare_results(rows)
    assert not c.checks["naive and physics rows within x1.5"]
    text = paper.results_markdown(c)
    assert "0.0252 / 0.0126 (2.00 ✗)" in text and "- ✗ naive and physics rows within x1.5" in text


def test_a_worlds_ratio_that_misses_the_papers_passes_only_where_the_real_flights_miss_it_the_same_way():
    from nanosysid.report import paper

    # on the real flights an LSTM 20 % better on ω than physics: 0.80 against the paper's
    # 35.8353 / 29.0866 = 1.2320, 35 % below it; the other cells the paper's own
    rows = {m: paper_like(m) for m in PAPER}
    rows["lstm"] = paper_like("lstm", {"w": 0.80 * 29.0866 / 35.8353})
    real = paper.compare_results(rows)
    world = {key: ours for key, (ours, _) in real.ratios.items()}
    world[("lstm", "w")] = 0.70   # below the paper's, as the real flights, and 0.70 / 0.80 = 0.875 of theirs
    world[("lstm", "p")] = 2.57 * 1.30  # 30 % above the paper's 5.9711 / 2.3223 = 2.5712, where the real flights meet it
    world[("lstm", "v")] = 1.57 * 0.80  # 20 % below the paper's 16.7207 / 10.6232 = 1.5740: within 25 %
    world[("residual", "R")] = 0.85  # 28 % below the paper's 6.0591 / 5.1013 = 1.1878; the real flights sit on it
    paper.compare_world(real, world)
    assert real.world[("lstm", "w")] == (0.70, paper.AS_REAL)
    assert real.world[("lstm", "p")][1] == paper.OFF and real.world[("residual", "R")][1] == paper.OFF
    assert real.world[("lstm", "v")][1] == paper.WITHIN and real.world[("phys_res", "p")][1] == paper.WITHIN
    check = "the default world's ratios within 25% of the paper's, or missing it as the real flights do"
    assert not real.checks[check]
    world[("lstm", "p")], world[("residual", "R")] = real.ratios[("lstm", "p")][0], real.ratios[("residual", "R")][0]
    again = paper.compare_results(rows)
    paper.compare_world(again, {key: r for key, r in world.items() if key != ("phys_res", "p")})
    assert again.checks[check] and ("phys_res", "p") not in again.world  # a cell the world lacks is left out
    # a world 45 % below the paper's, where the real flights are 35 % below: 0.6776 / 0.80 = 0.85 of theirs
    world[("lstm", "w")] = 0.55 * 1.2320
    third = paper.compare_results(rows)
    paper.compare_world(third, world)
    assert third.world[("lstm", "w")][1] == paper.AS_REAL
    world[("lstm", "w")] = 0.55  # 0.55 / 0.80 = 0.69 of the real flights' ratio: off
    fourth = paper.compare_results(rows)
    paper.compare_world(fourth, world)
    assert fourth.world[("lstm", "w")][1] == paper.OFF and not fourth.checks[check]
    text = paper.results_markdown(fourth)
    assert "| lstm / physics, the default world | 2.57 ✓ | 1.26 ✓ | 1.11 ✓ | 0.55 ✗ |" in text
    assert "| phys_res / physics, the default world |" not in paper.results_markdown(again)  # a row only whole
    text = paper.results_markdown(third)
    assert "| residual / physics, the default world | 1.74 ✓ | 1.18 ✓ | 1.19 ✓ | 1.22 ✓ |" in text
    assert "0.68 ≈ |" in text and json.loads(json.dumps(third.to_dict()))["world"]


def test_the_campaigns_world_table_holds_strict_json_with_an_open_interval_end_as_null():
    # a delay found at the search's largest has an interval open above
    from nanosysid.report.campaign import worlds_table

    cover = {"entry": "input_delay", "param": "delay [s]", "truth": 0.0819, "value": 0.08, "low": 0.0775,
             "high": float("inf"), "covered": True}
    row = {"world": 3, "seed": 7, "effects": {"telemetry_delay": 2.7}, "user": None, "user_strength": 0.0,
           "named": ["input_delay"], "coverage": [cover]}
    cell = worlds_table([row], ["telemetry_delay"])["coverage"][0]

    def refuse(constant):
        raise ValueError(f"non-standard JSON constant {constant}")

    (got,) = json.loads(cell, parse_constant=refuse)
    assert got["high"] is None and got["low"] == 0.0775 and got["covered"] is True


def test_the_world_comparison_measures_how_far_each_flights_mean_residual_moves():
    # three hovers on equal rotor speeds (no nominal torque), each with its own accelerometer
    # bias along y (0, 0.1, 0.2 m/s²) and its own constant pitch acceleration (0, 1, 2 rad/s²):
    # the spread of the flights' mean F_y residual is m * 0.1 and of tau_y J_y * 1 (std, n - 1)
    import yaml

    from nanosysid.dataio import Flight
    from nanosysid.report import realism
    from nanosysid.vehicle import Vehicle

    vehicle = Vehicle.from_mapping(yaml.safe_load(open("conf/vehicle/cf21bl.yaml")))
    t = np.arange(400) * 0.01
    u = np.full((400, 4), 2000.0)
    hover_az = vehicle.k_f * 4 * 2000.0**2 / vehicle.mass
    flights = []
    for k, (bias, alpha) in enumerate(((0.0, 0.0), (0.1, 1.0), (0.2, 2.0)), start=1):
        y = np.zeros((400, 13))
        y[:, 9] = 1.0
        y[:, 11] = alpha * t
        extra = {"ax_body": np.zeros(400), "ay_body": np.full(400, bias), "az_body": np.full(400, hover_az)}
        flights.append(Flight(f"melon_20250101_run{k}", t, u, y, extra))
    spread = realism.world_figures(flights, vehicle)["all"]
    assert spread["F_y residual, spread of the flights' means [mN]"] == pytest.approx(1e3 * vehicle.mass * 0.1)
    assert spread["tau_y residual, spread of the flights' means [mN·m]"] == pytest.approx(1e3 * vehicle.inertia[1])
    for ch in ("F_x", "F_z"):
        assert spread[f"{ch} residual, spread of the flights' means [mN]"] == pytest.approx(0.0, abs=1e-9)
    for ch in ("tau_x", "tau_z"):
        assert spread[f"{ch} residual, spread of the flights' means [mN·m]"] == pytest.approx(0.0, abs=1e-9)
    # beside flights whose pitch means move twice as far, the world's figure is half the real one: listed
    real = realism.world_figures([Flight(f.name, f.t, f.u, np.column_stack([f.y[:, :11], 2 * f.y[:, 11:12],
                                                                           f.y[:, 12:]]), f.extra)
                                  for f in flights], vehicle)
    rows = {r["figure"]: r for r in realism.compare({"all": spread}, {"all": real["all"]}, (0.02, 0.02))["rows"]}
    assert rows["tau_y residual, spread of the flights' means [mN·m]"]["ratio"] == pytest.approx(0.5)
    assert rows["tau_y residual, spread of the flights' means [mN·m]"]["off"]
    assert not rows["F_y residual, spread of the flights' means [mN]"]["off"]


def test_the_world_comparison_reads_the_rotors_reaction_in_the_yaw_residual():
    # a hover whose rotors swing in yaw at 3 Hz, Omega_i = b + s_i A sin(w t), with a rotor inertia
    # J_r: the body's yaw acceleration is (nominal -k_M sum s_i Omega_i² = -8 k_M b A sin(w t), plus
    # the reaction -J_r sum s_i dOmega_i/dt = -4 J_r A w cos(w t)) / J_z, integrated by hand; the
    # residual is the reaction alone, J_r comes back and the correlation is 1. A second flight adds
    # a yaw torque of another frequency (2.2 Hz) and the same RMS: the correlation is 1/sqrt(2)
    import yaml

    from nanosysid import dynamics
    from nanosysid.dataio import Flight
    from nanosysid.report import realism
    from nanosysid.vehicle import Vehicle

    vehicle = Vehicle.from_mapping(yaml.safe_load(open("conf/vehicle/cf21bl.yaml")))
    jr, b, amp, w, w2 = 3.0e-8, 1750.0, 40.0, 2 * np.pi * 3.0, 2 * np.pi * 2.2
    t = np.arange(6000) * 0.01
    spin = np.asarray(dynamics.SPIN)
    u = b + amp * np.sin(w * t)[:, None] * spin
    jz = vehicle.inertia[2]
    wz = (8 * vehicle.k_m * b * amp * np.cos(w * t) / w - 4 * jr * amp * np.sin(w * t)) / jz
    extra = {"ax_body": np.zeros(len(t)), "ay_body": np.zeros(len(t)),
             "az_body": np.full(len(t), vehicle.k_f * 4 * b**2 / vehicle.mass)}
    flights = []
    for k, disturbance in enumerate((0.0, 4 * jr * amp * w / w2), start=1):
        y = np.zeros((len(t), 13))
        y[:, 9] = 1.0
        y[:, 12] = wz - disturbance * np.cos(w2 * t) / jz  # a torque d sin(w2 t) integrated
        flights.append(Flight(f"chirp_20250101_run{k}", t, u, y, extra))
    pure = realism.yaw_reaction(flights[:1], vehicle)["chirp"]
    assert pure["J_r [kg m²]"] == pytest.approx(jr, rel=0.01)
    assert pure["correlation"] == pytest.approx(1.0, abs=1e-3)
    assert pure["yaw-differential rotor acceleration [rad/s² std]"] == pytest.approx(4 * amp * w / np.sqrt(2), rel=0.05)
    mixed = realism.yaw_reaction(flights[1:], vehicle)["chirp"]
    assert mixed["J_r [kg m²]"] == pytest.approx(jr, rel=0.02)
    assert mixed["correlation"] == pytest.approx(1 / np.sqrt(2), abs=0.03)
    # the 3 Hz swing is within the yaw loop's reach, one at 6 Hz beyond it: all of its power above 4 Hz
    above = "yaw-differential rotor acceleration above 4 Hz [% of its power]"
    assert pure[above] < 1.0
    fast = Flight("melon_20250101_run1", t, b + amp * np.sin(2 * w * t)[:, None] * spin, flights[0].y, extra)
    assert realism.yaw_reaction([fast], vehicle)["melon"][above] > 99.0
    # two runs of rotors of 2e-8 and 4e-8 kg m²: the mean 3e-8, and the 95 % half-width Student's
    # t with one degree of freedom (12.706) times the standard error (std 1.414e-8 over sqrt 2)
    runs = []
    for k, inertia in enumerate((2.0e-8, 4.0e-8), start=1):
        y = np.zeros((len(t), 13))
        y[:, 9] = 1.0
        y[:, 12] = (8 * vehicle.k_m * b * amp * np.cos(w * t) / w - 4 * inertia * amp * np.sin(w * t)) / jz
        runs.append(Flight(f"square_20250101_run{k}", t, u, y, extra))
    two = realism.yaw_reaction(runs, vehicle)["square"]
    assert two["J_r [kg m²]"] == pytest.approx(3.0e-8, rel=0.01)
    assert two["J_r, 95 % half-width over the runs [kg m²]"] == pytest.approx(12.706 * 1.0e-8, rel=0.01)


def test_the_world_comparison_splits_the_roll_residual_into_its_bands():
    # a hover whose roll torque is three sines, at 0.03, 0.3 and 1.6 Hz (whole cycles over the
    # 100 s), integrated by hand into the roll rate: each band between 0.1, 0.8 and 3.2 Hz holds
    # one sine, whose RMS is its amplitude over sqrt 2; nothing lies above 3.2 Hz, and the pitch
    # residual, with no torque, is zero in every band
    import yaml

    from nanosysid.dataio import Flight
    from nanosysid.report import realism
    from nanosysid.vehicle import Vehicle

    vehicle = Vehicle.from_mapping(yaml.safe_load(open("conf/vehicle/cf21bl.yaml")))
    b, t = 1750.0, np.arange(10000) * 0.01
    amps = {0.03: 0.4e-3, 0.3: 0.6e-3, 1.6: 0.2e-3}  # Hz: N m
    y = np.zeros((len(t), 13))
    y[:, 9] = 1.0
    y[:, 10] = sum(-a * np.cos(2 * np.pi * f * t) / (2 * np.pi * f * vehicle.inertia[0]) for f, a in amps.items())
    extra = {"ax_body": np.zeros(len(t)), "ay_body": np.zeros(len(t)),
             "az_body": np.full(len(t), vehicle.k_f * 4 * b**2 / vehicle.mass)}
    flights = [Flight("chirp_20250101_run1", t, np.full((len(t), 4), b), y, extra)]
    # the compare stage's single pass over the residual gives each analysis what it gives alone
    both = realism.analyses(flights, vehicle)
    assert both["torque_bands"] == realism.torque_bands(flights, vehicle)
    bands = both["torque_bands"]["chirp"]
    for band, f in (("below 0.1 Hz", 0.03), ("0.1-0.8 Hz", 0.3), ("0.8-3.2 Hz", 1.6)):
        assert bands[f"tau_x residual {band} [mN·m RMS]"] == pytest.approx(1e3 * amps[f] / np.sqrt(2), rel=0.03)
        assert bands[f"tau_y residual {band} [mN·m RMS]"] == pytest.approx(0.0, abs=1e-9)
    assert bands["tau_x residual above 3.2 Hz [mN·m RMS]"] < 0.01 * 1e3 * amps[0.3]


def _bobbing_hovers(drags, name, slow=None, noise=0.0, rng=None, samples=3000):
    """Hovers tilted 30 degrees in roll that bob along their body z axis at 0.4 Hz, ``v_z = V
    sin(w t)``, and drift along their body y axis (which the drag along z must not read), rotors
    steady at b: the accelerometer reads the nominal thrust less a drag ``K (4 b) v_z`` (one run
    per K of ``drags``), plus ``slow`` (N, a function of time and the run's generator) and white
    noise, over the mass. Returns the vehicle and the flights."""
    import yaml

    from nanosysid.dataio import Flight
    from nanosysid.vehicle import Vehicle

    vehicle = Vehicle.from_mapping(yaml.safe_load(open("conf/vehicle/cf21bl.yaml")))
    b, speed, w, half = 1750.0, 0.5, 2 * np.pi * 0.4, np.radians(15.0)
    t = np.arange(samples) * 0.01
    u = np.full((len(t), 4), b)
    y = np.zeros((len(t), 13))
    y[:, 6], y[:, 9] = np.sin(half), np.cos(half)  # qx, qw: 30 degrees of roll
    z_b, y_b = np.array([0.0, -0.5, np.sqrt(0.75)]), np.array([0.0, np.sqrt(0.75), 0.5])  # in the world
    v_z = speed * np.sin(w * t)
    y[:, 3:6] = v_z[:, None] * z_b + 0.4 * np.cos(w * t)[:, None] * y_b
    flights = []
    for k, drag in enumerate(drags, start=1):
        force = vehicle.k_f * 4 * b**2 - drag * 4 * b * v_z + (0.0 if slow is None else slow(t, rng))
        az = force / vehicle.mass + (rng.normal(0, noise, len(t)) if noise else 0.0)
        flights.append(Flight(f"{name}_20250101_run{k}", t, u, y,
                              {"ax_body": np.zeros(len(t)), "ay_body": np.zeros(len(t)), "az_body": az}))
    return vehicle, flights, speed


def test_the_world_comparison_reads_the_climb_drag_in_the_thrust_residual():
    # the drag alone is the thrust residual: K comes back and the correlation is 1. Two runs of
    # 2e-6 and 4e-6 kg/rad: the mean 3e-6 and the 95 % half-width Student's t with one degree of
    # freedom (12.706) times the standard error (std 1.414e-6 over sqrt 2)
    from nanosysid.report import realism

    vehicle, flights, speed = _bobbing_hovers((2.0e-6, 4.0e-6), "random")
    one = realism.climb_drag(flights[:1], vehicle)["random"]
    assert one["K_z [kg/rad]"] == pytest.approx(2.0e-6, rel=0.01)
    assert one["correlation"] == pytest.approx(1.0, abs=1e-3)
    assert one["body-z velocity [m/s std]"] == pytest.approx(speed / np.sqrt(2), rel=0.01)
    two = realism.climb_drag(flights, vehicle)["random"]
    assert two["K_z [kg/rad]"] == pytest.approx(3.0e-6, rel=0.01)
    assert two["K_z, 95 % half-width over the runs [kg/rad]"] == pytest.approx(12.706 * 1.0e-6, rel=0.01)


def _flapping_hovers(moments, name, slow=None, noise=0.0, rng=None, samples=3000):
    """Level hovers drifting along body x at 0.3 Hz and body y at 0.4 Hz, rotors steady at b (no
    nominal torque), whose roll and pitch rates answer a moment ``(E_x S_y, -E_y S_x)``, ``S =
    4 b v``, ``(E_x, E_y)`` one run per pair of ``moments``, plus ``slow`` (N m on both axes, a
    function of time and the run's generator), integrated by hand, with white gyro noise."""
    import yaml

    from nanosysid.dataio import Flight
    from nanosysid.vehicle import Vehicle

    vehicle = Vehicle.from_mapping(yaml.safe_load(open("conf/vehicle/cf21bl.yaml")))
    (jx, jy, _), b, speed = vehicle.inertia, 1750.0, 0.5
    wx_, wy_ = 2 * np.pi * 0.3, 2 * np.pi * 0.4
    t = np.arange(samples) * 0.01
    flights = []
    for k, (ex, ey) in enumerate(moments, start=1):
        y = np.zeros((len(t), 13))
        y[:, 9] = 1.0
        y[:, 3], y[:, 4] = speed * np.sin(wx_ * t), speed * np.sin(wy_ * t)
        # J dw/dt = E 4 b v: the rates are the moments' integrals, sin -> -cos / w
        y[:, 10] = -ex * 4 * b * speed * np.cos(wy_ * t) / (jx * wy_)
        y[:, 11] = ey * 4 * b * speed * np.cos(wx_ * t) / (jy * wx_)
        if slow is not None:
            y[:, 10] += slow(t, rng) / jx
            y[:, 11] += slow(t, rng) / jy
        if noise:
            y[:, 10:12] += rng.normal(0, noise, (len(t), 2))
        g = np.full(len(t), vehicle.gravity)
        flights.append(Flight(f"{name}_20250101_run{k}", t, np.full((len(t), 4), b), y,
                              {"ax_body": 0 * g, "ay_body": 0 * g, "az_body": g}))
    return vehicle, flights


def test_the_world_comparison_reads_the_drag_moment_in_the_slow_roll_and_pitch_residual():
    # the moment alone is the residual: E_x and E_y come back and their correlations are 1. Two
    # runs of E_x 0.6e-7 and 1.0e-7: the mean 0.8e-7 and the 95 % half-width Student's t with one
    # degree of freedom (12.706) times the standard error (std 0.2828e-7 over sqrt 2)
    from nanosysid.report import realism

    vehicle, flights = _flapping_hovers(((0.6e-7, 1.3e-7), (1.0e-7, 1.3e-7)), "square")
    one = realism.drag_moment(flights[:1], vehicle)["square"]
    assert one["E_x [kg m/rad]"] == pytest.approx(0.6e-7, rel=0.01)
    assert one["E_y [kg m/rad]"] == pytest.approx(1.3e-7, rel=0.01)
    assert one["correlation, x"] == pytest.approx(1.0, abs=1e-3) and one["correlation, y"] == pytest.approx(1.0, abs=1e-3)
    two = realism.drag_moment(flights, vehicle)["square"]
    assert two["E_x [kg m/rad]"] == pytest.approx(0.8e-7, rel=0.01)
    assert two["E_x, 95 % half-width over the runs [kg m/rad]"] == pytest.approx(12.706 * 0.2e-7, rel=0.01)
    assert two["E_y, 95 % half-width over the runs [kg m/rad]"] == pytest.approx(0.0, abs=1e-10)


def _climb_session(rng):
    # four bobbing hovers (K_z 2.8e-6 kg/rad), each with its own accelerometer noise (white, 0.2
    # m/s²) and a slow thrust disturbance of random phase
    def slow(t, rng):
        return 2e-3 * np.sin(2 * np.pi * 0.3 * t + rng.uniform(0, 2 * np.pi))

    vehicle, flights, _ = _bobbing_hovers((2.8e-6,) * 4, "chirp", slow, 0.2, rng, samples=2000)
    return vehicle, flights


def _flapping_session(rng):
    # four flapping hovers (E 0.9e-7 and 1.3e-7 kg m/rad), each with its own gyro noise (white,
    # 0.05 rad/s) and a slow torque of random phase
    def slow(t, rng):
        return 5e-5 * np.sin(2 * np.pi * 0.25 * t + rng.uniform(0, 2 * np.pi))

    return _flapping_hovers(((0.9e-7, 1.3e-7),) * 4, "chirp", slow, 0.05, rng, samples=2000)


@pytest.mark.parametrize("session, analysis, coefficient, truth, seed", [
    (_climb_session, "climb_drag", "K_z [kg/rad]", 2.8e-6, 7),
    (_flapping_session, "drag_moment", "E_x [kg m/rad]", 0.9e-7, 11)])
def test_a_regressions_interval_over_the_runs_covers_the_truth_about_95_percent_of_the_time(
        session, analysis, coefficient, truth, seed):
    # 300 sessions of four runs each; the 95 % interval over a session's runs covers the truth in
    # 95 % of the sessions (binomial std of the share over 300: 1.3 %)
    from nanosysid.report import realism

    name, unit = coefficient.split(" [")
    rng = np.random.default_rng(seed)
    covered = 0
    for _ in range(300):
        vehicle, flights = session(rng)
        est = getattr(realism, analysis)(flights, vehicle)["chirp"]
        covered += abs(est[coefficient] - truth) <= est[f"{name}, 95 % half-width over the runs [{unit}"]
    assert 0.92 <= covered / 300 <= 0.98


def test_the_world_comparison_reads_a_residuals_band_between_welchs_bins():
    # power spread evenly over 0 .. 0.7 Hz (random phases): half of it lies below 0.35 Hz, which
    # falls between Welch's 0.098 Hz bins (0.293 and 0.391)
    from nanosysid.report import realism

    rng = np.random.default_rng(0)
    f = np.fft.rfftfreq(60000, 0.01)  # 600 s: Welch's average over 117 segments
    x = np.fft.irfft(np.where((f > 0) & (f <= 0.7), np.exp(2j * np.pi * rng.random(len(f))), 0), 60000)
    assert realism._median_frequency(x, 0.01) == pytest.approx(0.35, abs=0.015)


def test_the_world_comparison_reads_how_each_sensors_noise_grows_with_the_rotors_motion():
    # five flights whose rotors swing at 0.5 Hz with amplitudes A (mean |dOmega/dt| = 4 A f = 2 A),
    # each sensor's white noise n0 sqrt(1 + (a / ref)²) with its own ref: the law gives the refs back
    from nanosysid.dataio import Flight
    from nanosysid.report import realism

    rng = np.random.default_rng(0)
    t = np.arange(6000) * 0.01
    ref = {"gyro": 1200.0, "accelerometer": 1500.0, "rotor speed": 1000.0}
    n0 = {"gyro": 0.008, "accelerometer": 0.01, "rotor speed": 3.0}
    flights = []
    for k, amp in enumerate((50, 150, 300, 450, 600), start=1):
        std = {s: n0[s] * np.sqrt(1 + (2 * amp / ref[s]) ** 2) for s in ref}
        u = 1750 + amp * np.sin(np.pi * t)[:, None] * np.ones(4) + rng.normal(scale=std["rotor speed"], size=(len(t), 4))
        y = np.zeros((len(t), 13))
        y[:, 9] = 1.0
        y[:, 10:13] = rng.normal(scale=std["gyro"], size=(len(t), 3))
        extra = {c: rng.normal(scale=std["accelerometer"], size=len(t)) for c in ("ax_body", "ay_body", "az_body")}
        flights.append(Flight(f"chirp_20250101_run{k}", t, u, y, extra))
    law = realism.noise_law(flights)
    for sensor, r in ref.items():
        assert law[sensor] == pytest.approx(r, rel=0.1), sensor
    # a noise that does not grow has no finite ref
    for f in flights:
        f.y[:, 10:13] = rng.normal(scale=0.008, size=(len(t), 3))
    assert realism.noise_law(flights)["gyro"] > 5 * ref["gyro"]


def test_the_discovery_reports_figures_name_only_what_they_draw():
    from nanosysid.report.discovery import figure_lines, horizon_caption

    # real flights have no oracle and no state limit: the caption must not promise them
    rig = {"nominal (physics_full)": 0, "discovered (physics+induced_drag)": 0}
    assert horizon_caption(rig) == "nominal and discovered"
    world = {**rig, "state limit (true dynamics of the state)": 0, "oracle": 0}
    assert horizon_caption(world) == "nominal, discovered, state limit and oracle"
    # two findings of one label share one figure: it is drawn once, and the second points to it
    shown = set()
    first = figure_lines("unnamed (F_y)", "figures/finding_3.png", "F_y", shown)
    second = figure_lines("unnamed (F_y)", "figures/finding_3.png", "F_y", shown)
    assert sum(line.startswith("![") for line in first + second) == 1
    assert "(figures/finding_3.png)" in second[0]


def test_the_discovery_report_sets_the_worlds_effects_beside_the_verdicts_and_names_a_false_one():
    from nanosysid.report.discovery import _separate_text, verdicts_markdown, world_lines

    world = {"rotor_drag": {"strength": 1.0, "described_by": ["drag_moment", "induced_drag"]},
             "turbulence": {"strength": 1.0, "described_by": []}}
    findings = [{"verdict": "named", "name": "induced_drag", "alternatives": [], "channels": ["F_x"], "evidence": {}},
                {"verdict": "named", "name": "slow_actuation", "alternatives": [], "channels": ["F_z"], "evidence": {}},
                {"verdict": "unstable", "name": None, "alternatives": ["battery_thrust"], "channels": ["F_z"],
                 "evidence": {}}]
    text = "\n".join(world_lines(world, findings))
    assert "| `rotor_drag` | 1 | `drag_moment`, `induced_drag` | `induced_drag` named |" in text
    assert "| `turbulence` | 1 | (no entry: an effect of time) | no entry of it named |" in text
    # a name no effect of the world has is said, an unstable one is no name
    assert text.rstrip().endswith("**Named or ambiguous and in no effect of the world**: `slow_actuation`")
    # an unstable residual with no entry says what it would have been, not an entry it has not
    line = verdicts_markdown([{"verdict": "unstable", "name": None, "alternatives": [], "channels": ["F_x"],
                               "evidence": {"was": "not a function of the state"}}])
    assert "- unstable (F_x): not a function of the state not reached" in line
    # rivals the library separates by one manoeuvre get it once, not once each
    one = _separate_text({"drag_moment": "fast passes", "induced_drag_moment": "fast passes"})
    assert one.count("fast passes") == 1 and "`drag_moment` and `induced_drag_moment`" in one
    two = _separate_text({"cg_offset": "throttle steps", "rotor_spread": "yaw turns"})
    assert two == "`cg_offset`: throttle steps; `rotor_spread`: yaw turns"
