"""Config: params.yaml is the composition of conf/, and every config group composes."""

from pathlib import Path

import pytest
import yaml

from nanosysid import config
from nanosysid.models import build_from_config
from nanosysid.models.learned import build_model, save_checkpoint
from nanosysid.models.train_stage import hparams_from_config

ROOT = Path(__file__).resolve().parents[1]


def test_committed_params_yaml_is_the_composition_of_conf():
    composed = config.compose_text(conf_dir=ROOT / "conf")
    committed = (ROOT / "params.yaml").read_text()
    assert committed == composed, "params.yaml is stale: run `make params` and commit it"


@pytest.mark.parametrize("name", sorted(p.stem for p in (ROOT / "conf" / "model").glob("*.yaml")))
def test_every_model_config_composes_and_builds(name, tmp_path):
    cfg = yaml.safe_load(config.compose_text([f"+model@models.probe={name}"], conf_dir=ROOT / "conf"))
    m = cfg["models"]["probe"]
    assert m["artifact"]  # every model names what evaluate depends on
    # the artifacts are pipeline outputs: make them here from the config itself
    if m.get("identified"):
        m["identified"] = str(tmp_path / "params.json")
        (tmp_path / "params.json").write_text('{"k_f": 3.7e-08, "k_m": 7.7e-11}')
    if m["kind"] == "learned":
        hp = hparams_from_config(m)
        m["checkpoint"] = str(tmp_path / "model.pt")
        save_checkpoint(build_model(hp), hp, tmp_path / "model.pt")
    if m["kind"] == "discovered":
        from nanosysid.discover.model import save_model
        from nanosysid.vehicle import Vehicle

        m["model"] = str(tmp_path / "model.json")
        save_model(tmp_path / "model.json", Vehicle(), {"rotor_drag": {"coefficients": [1e-6, 1e-6]}}, 0.01)
    assert callable(build_from_config(m))


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
    cfg = config.load_params(["eval.horizon=20", "+extra.flag=true", "~split.test"], path=ROOT / "params.yaml")
    assert cfg.eval.horizon == 20 and cfg.extra.flag is True and "test" not in cfg.split
    with pytest.raises(config.ConfigError, match="no_such_key"):
        config.load_params(["no_such_key=1"], path=ROOT / "params.yaml")
    with pytest.raises(config.ConfigError, match="not found"):
        config.load_params(path=tmp_path / "params.yaml")
