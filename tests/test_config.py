"""Config: params.yaml is the composition of conf/, and every config group composes."""

import os
import re
import sys
import shutil
from pathlib import Path

import pytest
import torch
import yaml

import dataclasses
import fnmatch

import numpy as np

from nanosysid import config, synthetic
from nanosysid.predictors import KINDS, build_from_options
from nanosysid.models.learned import build_model, save_checkpoint
from nanosysid.vehicle import Vehicle

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("root,params", sorted(config.ROOTS.items()))
def test_committed_params_yaml_is_the_composition_of_conf(root, params):
    composed = config.compose_text(conf_dir=ROOT / "conf", root=root)
    committed = (ROOT / params).read_text()
    assert committed == composed, f"{params} is stale: run `make params` and commit it"


def test_the_rig_pipeline_shares_no_path_with_the_simulated_worlds():
    sim = yaml.safe_load(config.compose_text(conf_dir=ROOT / "conf"))
    rig = yaml.safe_load(config.compose_text(conf_dir=ROOT / "conf", root="rig"))
    keys = ("preprocess.extract_dir", "preprocess.sync_dir", "preprocess.flights_dir", "preprocess.report_dir",
            "paths.split", "paths.eval", "paths.train_logs", "identify.out_dir", "report.markdown", "visualize.out_dir",
            "discover.out_dir", "discover.report_dir", "models.lstm.checkpoint", "models.phys_res.checkpoint")

    def get(cfg, key):
        for part in key.split("."):
            cfg = cfg[part]
        return cfg

    assert all(get(rig, k) != get(sim, k) and get(rig, k).startswith(("processed/rig", "reports/rig", "models-rig"))
               for k in keys)
    assert rig["data"]["source"] == "rig" and "oracle" not in rig["models"] and set(rig["models"]) == set(sim["models"]) - {"oracle"}


@pytest.mark.parametrize("name", sorted(p.stem for p in (ROOT / "conf" / "model").glob("*.yaml")))
def test_every_model_config_composes_and_predicts(name, tmp_path):
    from nanosysid.identify import Fit, write_identified
    from nanosysid.models.training import network_spec, physics_base

    cfg = yaml.safe_load(config.compose_text([f"+model@models.probe={name}"], conf_dir=ROOT / "conf"))
    m = cfg["models"]["probe"]
    assert m["artifact"]  # every model names what evaluate depends on
    if m["kind"] == "external" and not (ROOT / m["artifact"]).exists():
        pytest.skip(f"{name}: a model of the user's, fitted on {m['artifact']}, which the pipeline makes")
    # the artifacts are pipeline outputs: make them here from the config itself
    fit = Fit(coef=3.7e-8, stderr=0.0, r2=1.0, intercept=0.0, n=1)
    write_identified(tmp_path / "params.json", fit, dataclasses.replace(fit, coef=7.7e-11), [])
    for block in (m, m.get("physics") or {}):
        if block.get("identified"):
            block["identified"] = str(tmp_path / "params.json")
    if m["kind"] == "learned":
        m["checkpoint"] = str(tmp_path / "model.pt")
        save_checkpoint(build_model(network_spec(m), physics_base(m)), network_spec(m), tmp_path / "model.pt")
    if m["kind"] == "discovered":
        from nanosysid.discover.model import save_discovered

        m["model"] = str(tmp_path / "model.json")
        save_discovered(tmp_path / "model.json", Vehicle(), {"induced_drag": {"coefficients": [1e-6, 1e-6]}}, 0.01)
    flight = synthetic.synthetic_flights(["melon_x_run1"], 60, seed=1)[0]
    y0, u = flight.y[:5], np.stack([flight.u[k:k + 7] for k in range(5)])
    predictor = build_from_options(m)
    # a timed predictor (the oracle replays each flight's disturbances) is told where the windows start
    timed = {"t0": flight.t[:5] - flight.t[0], "flight": flight.name} if getattr(predictor, "timed", False) else {}
    pred = predictor(y0, u, **timed)
    assert pred.shape == (5, 7, 13) and np.isfinite(pred).all()


def test_learned_and_exported_models_are_models_of_the_config():
    cfg = yaml.safe_load(config.compose_text([], conf_dir=ROOT / "conf"))
    learned = {n for n, m in cfg["models"].items() if m["kind"] == "learned"}
    assert set(cfg["learned"]) == learned
    assert set(cfg["export"]["models"]) <= {n for n, m in cfg["models"].items() if KINDS[m["kind"]].export}
    assert all(cfg["export"]["models"][n] == {k: cfg["models"][n][k] for k in ("artifact", "code")}
               for n in cfg["export"]["models"])
    assert all(cfg["learned"][n] == cfg["models"][n]["code"] for n in cfg["learned"])
    # every model's own code is a file of the project
    assert all((ROOT / m["code"]).is_file() for m in cfg["models"].values())


def test_the_schema_and_conf_name_the_same_settings():
    """Every setting of every composition (each data source, each launcher, the optional blocks
    set and unset) has its kind in the one schema, and every schema entry is the kind of some
    setting (none stale, none shadowed)."""
    from nanosysid import settings

    used = set()
    for root, overrides in (("config", []), ("config", ["data=csv", "~model@models.oracle"]),
                            ("config", ["data=sim_direct"]), ("config", ["launcher=slurm"]),
                            ("config", ["+sim.flight.gains.kR_z=0.005", "models.residual.train.scheduler=null"]),
                            ("rig", [])):
        composed = yaml.safe_load(config.compose_text(overrides, conf_dir=ROOT / "conf", root=root))
        # an external model's own arguments (a user's, the README's) are its callable's to check
        external = tuple(f"models.{n}." for n, m in composed["models"].items() if m["kind"] == "external")
        for key, _ in settings.leaves(composed):
            if key.startswith(external) and key.rpartition(".")[2] not in ("kind", "artifact", "code"):
                continue
            entry = next((i for i, (pattern, _) in enumerate(settings.SCHEMA) if fnmatch.fnmatchcase(key, pattern)), None)
            assert entry is not None, f"{key}: no kind in nanosysid.settings.SCHEMA"
            used.add(entry)
    assert [p for i, (p, _) in enumerate(settings.SCHEMA) if i not in used] == []


def test_the_librarys_defaults_are_read_from_conf(tmp_path, monkeypatch):
    # a value changed in conf/ is the library's new default, with nothing else to edit; a value
    # without a field (or a field without a value) is refused when the class is made
    from nanosysid import settings

    conf = tmp_path / "conf"
    shutil.copytree(ROOT / "conf", conf)
    text = (conf / "vehicle/cf21bl.yaml").read_text()
    (conf / "vehicle/cf21bl.yaml").write_text(re.sub(r"^mass: 0\.045", "mass: 0.05", text, flags=re.M))
    monkeypatch.setattr(settings, "CONF", conf)
    settings._read.cache_clear()
    try:
        fields = {f.name: f.type for f in dataclasses.fields(Vehicle)}
        made = settings.configured("vehicle/cf21bl.yaml")(type("Made", (), {"__annotations__": dict(fields)}))
        assert made().mass == 0.05 and Vehicle().mass == 0.045  # the library's own class is read once, at import
        (conf / "vehicle/cf21bl.yaml").write_text(text + "wings: 2\n")
        settings._read.cache_clear()
        with pytest.raises(TypeError, match=r"cf21bl\.yaml: the file and Again disagree: no value for \[\], no "
                                            r"field for \['wings'\]"):
            settings.configured("vehicle/cf21bl.yaml")(type("Again", (), {"__annotations__": dict(fields)}))
    finally:
        monkeypatch.undo()
        settings._read.cache_clear()


@pytest.mark.parametrize("name", sorted(p.stem for p in (ROOT / "conf" / "data").glob("*.yaml")))
def test_every_data_config_composes(name):
    cfg = yaml.safe_load(config.compose_text([f"data={name}"], conf_dir=ROOT / "conf"))
    assert cfg["data"]["flights_dir"] and cfg["data"]["source"] == name


def test_real_data_without_the_oracle_leaves_discovery_without_one():
    cfg = yaml.safe_load(config.compose_text(["data=csv", "~model@models.oracle"], conf_dir=ROOT / "conf"))
    assert "oracle" not in cfg["models"] and cfg["discover"]["oracle"] is None
    cfg = yaml.safe_load(config.compose_text([], conf_dir=ROOT / "conf"))
    assert cfg["discover"]["oracle"] == cfg["models"]["oracle"]


def test_each_model_has_its_own_key_and_the_vehicle_is_resolved():
    cfg = config.load_params(path=ROOT / "params.yaml")
    assert set(cfg.models) >= {"naive", "physics", "physics_full"}
    assert cfg.models.physics.vehicle.k_f == cfg.vehicle.k_f


def test_overrides_on_params(tmp_path):
    cfg = config.load_params(["eval.horizon=20", "~split.test"], path=ROOT / "params.yaml")
    assert cfg.eval.horizon == 20 and "test" not in cfg.split
    with pytest.raises(config.ConfigError, match="adds the setting 'extra.flag', which params.yaml does not hold"):
        config.load_params(["+extra.flag=true"], path=ROOT / "params.yaml")
    with pytest.raises(config.ConfigError, match="no_such_key"):
        config.load_params(["no_such_key=1"], path=ROOT / "params.yaml")
    with pytest.raises(config.ConfigError, match="not found"):
        config.load_params(path=tmp_path / "params.yaml")


def test_a_missing_interpolation_is_named_where_it_is_written_not_where_it_is_followed(tmp_path):
    # a model's block that follows paths.split (the README's external model) comes first in the
    # file: the error still names the setting the user wrote
    own = tmp_path / "params.yaml"
    own.write_text("models:\n  mine:\n    split: ${paths.split}\npaths:\n  split: ${nope.key}\n")
    with pytest.raises(config.ConfigError, match=r"params\.yaml: paths\.split: Interpolation key 'nope\.key' not found"):
        config.load_params(path=own)


def test_a_setting_derived_from_another_follows_its_override(tmp_path, monkeypatch):
    monkeypatch.chdir(ROOT)
    out = tmp_path / "fit"
    cfg = config.load_params([f"identify.out_dir={out}"])
    want = f"{out}/params.json"
    # what evaluate, train (physics + residual) and discover read, and what export depends on
    assert (cfg.models.physics.identified == cfg.models.physics_full.identified == cfg.models.phys_res.physics.identified
            == cfg.discover.identified == cfg.export.models.physics.artifact == want)
    # a derived setting given its own value keeps it, on the command line ...
    cfg = config.load_params([f"identify.out_dir={out}", "discover.identified=null"])
    assert cfg.discover.identified is None and cfg.models.physics.identified == want
    # ... and in params.yaml (as `dvc exp run -S models.physics.identified=x` writes it)
    text = (ROOT / "params.yaml").read_text()
    own = tmp_path / "params.yaml"
    own.write_text(text.replace("identified: models/physics/params.json", "identified: mine.json", 1))
    cfg = config.load_params([f"identify.out_dir={out}"], path=own)
    assert cfg.models.physics.identified == "mine.json" and cfg.models.physics_full.identified == want


def test_a_conf_file_edited_between_two_stages_of_one_process_is_read_again(tmp_path):
    # what a setting is derived from, read once per process for every stage it runs: an edit of
    # conf/ in between (the same length, at once) must reach the next stage
    conf = tmp_path / "conf"
    shutil.copytree(ROOT / "conf", conf)
    assert config.interpolations(conf_dir=conf)["discover.identified"] == "${identify.out_dir}/params.json"
    path = conf / "config.yaml"
    text = path.read_text()
    assert "${identify.out_dir}/params.json" in text
    path.write_text(text.replace("${identify.out_dir}/params.json", "${identify.out_dir}/paramz.json"))
    assert config.interpolations(conf_dir=conf)["discover.identified"] == "${identify.out_dir}/paramz.json"
    (conf / "model" / "naive.yaml").write_text((conf / "model" / "naive.yaml").read_text() + "note: ${seed}\n")
    assert config.interpolations(conf_dir=conf)["models.naive.note"] == "${seed}"


def readme_blocks(section: str) -> list[str]:
    """The code blocks of a section of the README or of a docs page, in order."""
    import docpages

    text = docpages.text()
    start = text.index(section)
    end = min(i for i in (text.find("\n## ", start + 1), text.find("\n# ", start + 1), len(text)) if i >= 0)
    return re.findall(r"```\w*\n(.*?)```", text[start:end], flags=re.S)


def readme_model() -> tuple[str, list[str]]:
    """The README's new network (``gru``) and its section's code blocks, renamed where the tree
    holds a model or a network of that name already (a user's that followed the README)."""
    import itertools

    import nanosysid.models.components as components

    blocks = readme_blocks("## Your own model")
    taken = {p.stem for p in (ROOT / "conf" / "model").glob("*.yaml")} | {
        p.stem for d in components.__path__ for p in Path(d).glob("*.py")}
    name = "gru"
    if name in taken:
        new = next(f"{name}{i}" for i in itertools.count(2) if f"{name}{i}" not in taken)
        blocks = [re.sub(rf"\b{name}\b", new, b) for b in blocks]
        name = new
    return name, blocks


def test_adding_a_model_takes_the_three_files_the_readme_shows(tmp_path, monkeypatch):
    """The README's GRU: its component, its config file and the config's list of models are
    all it takes to train it, score it and check its checkpoint."""
    import nanosysid.models.components as components
    from nanosysid.dataio import write_flight_csv
    from stages import evaluate, train

    gru, (component, model_yaml, config_lines, _) = readme_model()
    (tmp_path / "networks").mkdir()
    (tmp_path / "networks" / f"{gru}.py").write_text(component)
    monkeypatch.setattr(components, "__path__", [*components.__path__, str(tmp_path / "networks")])
    conf = tmp_path / "conf"
    shutil.copytree(ROOT / "conf", conf)
    (conf / "model" / f"{gru}.yaml").write_text(model_yaml)
    defaults_line, learned_line = [line for line in config_lines.splitlines() if line.strip()]
    text = (conf / "config.yaml").read_text()
    text = text.replace("  - _self_\n", f"{defaults_line}\n  - _self_\n", 1)
    text = text.replace("\nlearned:\n", f"\nlearned:\n{learned_line}\n", 1)
    (conf / "config.yaml").write_text(text)
    params = tmp_path / "params.yaml"
    config.compose([], out=params, conf_dir=conf)

    split = tmp_path / "split"
    made = synthetic.synthetic_flights(["chirp_x_run1", "chirp_x_run4", "melon_x_run1"], 300, seed=5)
    for f, part in zip(made, ("train", "train", "test")):
        write_flight_csv(f, split / part / f"{f.name}.csv")
    overrides = [f"paths.split={split}", f"paths.train_logs={tmp_path / 'logs'}", f"paths.eval={tmp_path / 'eval'}",
                 f"models.{gru}.checkpoint={tmp_path / 'gru.pt'}", f"models.{gru}.train.epochs=1",
                 f"models.{gru}.train.stride=20", "eval.horizon=20", f"models.{gru}.train.horizon=20"]
    cfg = config.load_params(overrides, path=params)
    assert gru in cfg.learned and cfg.models[gru].train.optimizer.lr == 3.0e-3
    assert cfg.models[gru].train.batch_size == cfg.models.residual.train.batch_size  # the shared settings
    summary = train.main(cfg, gru)
    assert summary["epochs"] == 1
    scores = evaluate.main(cfg, gru)
    assert scores.n_windows == 300 - 20 and all(np.isfinite(v) for v in scores.simerr.values())
    raw = torch.load(tmp_path / "gru.pt", weights_only=True)
    assert raw["network"] == {"name": gru, "options": {"hidden": 48}}


def test_a_model_that_is_no_network_enters_through_its_config(tmp_path, monkeypatch):
    """The README's external model: a callable named by ``_target_`` builds the predictor; here
    one that holds the state (the naive model's prediction), so its scores must be the naive
    model's."""
    from nanosysid import protocol
    from nanosysid.predictors import build_from_options, predictor

    *_, block = readme_blocks("## Your own model")
    (tmp_path / "mymodels").mkdir()
    (tmp_path / "mymodels" / "__init__.py").write_text("")
    (tmp_path / "mymodels" / "arx.py").write_text(
        "import numpy as np\n\n\ndef fit(order, split):\n"
        "    def predict(y0, u):\n        return np.repeat(np.asarray(y0)[:, None, :], u.shape[1], axis=1)\n"
        "    return predict\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    for module in ("mymodels", "mymodels.arx"):  # a user's own, imported by another test
        monkeypatch.delitem(sys.modules, module, raising=False)
    options = yaml.safe_load(block.replace("${paths.split}", str(tmp_path / "split")))
    flights = synthetic.synthetic_flights(["melon_x_run1"], 200, seed=3)
    own = protocol.evaluate(build_from_options(options), flights, horizon=10)
    naive = protocol.evaluate(predictor("naive"), flights, horizon=10)
    assert own.simerr == naive.simerr and own.n_windows == naive.n_windows == 200 - 10
    with pytest.raises(config.ConfigError, match="mymodels.arx.nothing"):
        build_from_options({**options, "_target_": "mymodels.arx.nothing"})


@pytest.mark.parametrize("override, message", [
    ("eval.horizon=abc", r"eval\.horizon must be a positive whole number, got 'abc'"),
    ("eval.horizon=2.5", r"eval\.horizon must be a positive whole number, got 2\.5"),
    ("eval.horizon=true", r"eval\.horizon must be a positive whole number, got True"),
    ("eval.horizon=-5", r"eval\.horizon must be a positive whole number, got -5"),
    ("eval.batch_size=0", r"eval\.batch_size must be a positive whole number, got 0"),
    ("models.physics.substeps=0", r"models\.physics\.substeps must be a positive whole number, got 0"),
    ("models.physics.dt=-0.01", r"models\.physics\.dt must be a positive number, got -0\.01"),
    ("vehicle.mass=heavy", r"vehicle\.mass must be a positive number, got 'heavy'"),
    ("vehicle.k_f=nan", r"vehicle\.k_f must be a positive number, got nan"),
    ("vehicle.k_f=-3.7e-8", r"vehicle\.k_f must be a positive number, got -3\.7e-08"),
    ("preprocess.filter.velocity=60", r"preprocess\.filter\.velocity = 60 Hz is at or above the Nyquist frequency 50 Hz"),
    ("preprocess.sync.rate=0", r"preprocess\.sync\.rate must be a positive number, got 0"),
    ("preprocess.sync.max_lag=-1", r"preprocess\.sync\.max_lag must be a positive number, got -1"),
    ("sim.flight.feedforward=1.5", r"sim\.flight\.feedforward must be a number from 0 to 1, got 1\.5"),
    ("sim.flight.trajectories.melon.omega_start=-1",
     r"sim\.flight\.trajectories\.melon\.omega_start must be a number >= 0, or null, got -1"),
    ("sim.flight.noise.gyro=[0.1,0.2]",
     r"sim\.flight\.noise\.gyro must be one number, or three \(roll, pitch, yaw\), got \[0\.1, 0\.2\]"),
    ("vehicle.inertia=[1e-5,2e-5]", r"vehicle\.inertia must be three numbers \(body axes x, y, z\), got \[1e-05, 2e-05\]"),
    ("discover.sindy=maybe", r"discover\.sindy must be true or false, got 'maybe'"),
    ("report.markdown=5", r"report\.markdown must be text, got 5"),
    ("launcher.kind=pbs", r"launcher\.kind must be one of local, slurm, got 'pbs'"),
])
def test_bad_setting_values_are_one_clear_error(override, message):
    with pytest.raises(config.ConfigError, match=rf"params\.yaml with overrides: {message}"):
        config.load_params([override], path=ROOT / "params.yaml")


def test_stage_reports_a_bad_setting_without_traceback(tmp_path):
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "stages.evaluate", "physics", "eval.horizon=abc"], cwd=ROOT,
                       capture_output=True, text=True)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.strip().splitlines() == ["error: params.yaml with overrides: eval.horizon must be a positive whole "
                                             "number, got 'abc'"]


@pytest.mark.parametrize("old_name", ["nanosysid.bags.sync", "nanosysid.bags.filtering", "nanosysid.benchmark",
                                      "nanosysid.worlds"])
def test_the_old_module_names_are_gone_after_their_release(old_name):
    import importlib

    with pytest.raises(ModuleNotFoundError):
        importlib.import_module(old_name)


def test_the_old_name_of_the_preprocess_group_is_accepted_for_a_release_with_a_warning(tmp_path):
    """``recording.*`` overrides (the group's name before ``preprocess``) still set the same
    values, on a stage's command line and when composing ``params.yaml``, and say the new name."""
    params = ROOT / "params.yaml"
    with pytest.warns(FutureWarning, match=r"recording\.sync\.max_lag: this setting is now preprocess\.sync\.max_lag"):
        cfg = config.load_params(["recording.sync.max_lag=0.25", "recording.filter.order=2"], path=params)
    assert cfg.preprocess.sync.max_lag == 0.25 and cfg.preprocess.filter.order == 2 and "recording" not in cfg
    with pytest.warns(FutureWarning, match="now preprocess.filter.max_gap"):
        text = config.compose_text(config.renamed(["recording.filter.max_gap=7"]), conf_dir=ROOT / "conf")
    assert yaml.safe_load(text)["preprocess"]["filter"]["max_gap"] == 7
    # a value is not renamed, nor a key that only contains the old name
    assert config.renamed(["data.source=recording", "sim.recording_rate=1"]) == ["data.source=recording",
                                                                                 "sim.recording_rate=1"]


def test_the_command_line_runs_a_stage_of_the_project_from_any_directory(tmp_path):
    import subprocess
    import sys

    def cli(*args):
        return subprocess.run([sys.executable, "-m", "nanosysid.cli", *args], cwd=tmp_path, capture_output=True,
                              text=True, env={**os.environ, "PYTHONPATH": str(ROOT / "src")})

    top = cli("--help")
    assert top.returncode == 0 and "evaluate" in top.stdout and "discover" in top.stdout, top
    evaluate = cli("evaluate", "--help")
    assert evaluate.returncode == 0, evaluate.stderr
    assert "models.<model>" in evaluate.stdout and "eval" in evaluate.stdout.split("settings it reads")[1]
    assert "lstm" in evaluate.stdout and "model configs" in evaluate.stdout
    wrong = cli("evalute")
    assert wrong.returncode == 2 and "no stage 'evalute'" in wrong.stderr and "evaluate" in wrong.stderr
    # a setting out of its rules is the stage's one-line error, not a traceback, wherever it is run from
    bad = cli("split", "eval.horizon=-3")
    assert bad.returncode == 2 and "Traceback" not in bad.stderr and "eval.horizon" in bad.stderr, bad.stderr


def test_a_physics_model_says_whose_k_f_and_k_m_it_has(tmp_path, caplog):
    from nanosysid.identify import Fit, write_identified
    from nanosysid.predictors import predictor

    fit = Fit(coef=3.5e-8, stderr=0.0, r2=1.0, intercept=0.0, n=1)
    write_identified(tmp_path / "params.json", fit, dataclasses.replace(fit, coef=6.5e-11), [])
    with caplog.at_level("INFO"):
        nominal = predictor("physics")
        identified = predictor("physics", identified=str(tmp_path / "params.json"))
    said = [r.getMessage() for r in caplog.records]
    assert "not identified" in said[0] and "3.72e-08" in said[0]  # the paper's vehicle
    assert str(tmp_path / "params.json") in said[1] and "3.5e-08" in said[1] and "6.5e-11" in said[1]
    assert identified.step.vehicle.k_f == 3.5e-8 and nominal.step.vehicle.k_f == Vehicle().k_f



def test_the_optimiser_check_reads_torchs_classes_without_loading_torch():
    # a stage that never uses torch (split, sync) reads and checks the whole config without
    # loading it, and the names read from torch's source are every class the loaded modules hold
    import subprocess
    import sys

    code = ("import inspect, sys; from nanosysid import config; config.load_params(path=sys.argv[1]); "
            "names = {m: config._module_names(m) for m in ('torch.optim', 'torch.optim.lr_scheduler')}; "
            "loaded = 'torch' in sys.modules; import torch.optim, torch.optim.lr_scheduler; "
            "missing = sorted(f'{m}.{n}' for m in names for n, v in vars(sys.modules[m]).items() "
            "if inspect.isclass(v) and n not in names[m]); "
            "print(loaded, missing, 'Adamm' in names['torch.optim'], 'Adam' in names['torch.optim.lr_scheduler'])")
    out = subprocess.run([sys.executable, "-c", code, str(ROOT / "params.yaml")], capture_output=True, text=True,
                         check=True).stdout.split("\n")[0]
    assert out == "False [] False False", out
