"""The settings' files and the command line's forms a user gets wrong: a composition of values the
rules refuse is never written, a params file that is no YAML, an interpolation of a missing key, a
deleted key, a typo in a key, and the campaign's own bounds; each is one line naming the setting,
exit 2, no traceback."""

from __future__ import annotations

from pathlib import Path

import pytest

from nanosysid import config
from stages import campaign as campaign_stage
from stages import split as split_stage
from stages.common import run_stage

CLASS = "unchecked setting"

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("override, words", [
    ("eval.horizon=abc", "eval.horizon must be a positive whole number, got 'abc'"),
    ("models.physics.substeps=0", "models.physics.substeps must be a positive whole number, got 0"),
    ("rig.logs.pole_pairs=0", "rig.logs.pole_pairs must be a positive number, got 0"),
    ("eval.horizn=10", "Could not override 'eval.horizn'"),
])
def test_a_composition_the_rules_refuse_is_never_written(override, words, capsys, monkeypatch):
    monkeypatch.chdir(ROOT)  # the composer writes the project's params files; a refusal writes none
    before = {p: p.read_bytes() for p in (ROOT / "params.yaml", ROOT / "params-rig.yaml")}
    assert config.main(["compose", override]) == 2
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert {p: p.read_bytes() for p in before} == before


@pytest.mark.parametrize("argv, words", [
    (["--params", "{bad}"], r"{bad}: not a readable YAML file \(line 2\)"),
    (["paths.split=${nope.key}"], r"params.yaml: paths.split: Interpolation key 'nope.key' not found"),
    (["~split.train"], r"the setting 'split.train' is missing \(deleted by ~split.train\); the split stage reads it"),
])
def test_a_params_file_or_override_a_stage_cannot_read_is_one_line(tmp_path, argv, words, capsys, monkeypatch):
    import re

    monkeypatch.chdir(ROOT)
    bad = tmp_path / "bad.yaml"
    bad.write_text("{{{\n")
    argv = [a.replace("{bad}", str(bad)) for a in argv]
    rc = run_stage(split_stage.main, description="", argv=[*argv, f"paths.split={tmp_path / 'split'}"]
                   if "paths.split=" not in " ".join(argv) else argv)
    err = capsys.readouterr().err
    assert rc == 2 and re.search(words.replace("{bad}", re.escape(str(bad))), err), err
    assert "Traceback" not in err and not (tmp_path / "split").exists()


@pytest.mark.parametrize("overrides, words", [
    (["campaign.user_share=1.5"], "campaign.user_share must be a number from 0 to 1, got 1.5"),
    (["campaign.max_effects=50"], "campaign: max_effects (campaign.max_effects) = 50; a world draws 0 to at most"),
    (["campaign.duration=0.3"], "campaign.duration = 0.3 s; each world's flights need at least 3 s"),
])
def test_the_campaigns_bounds_are_named_before_any_world_flies(tmp_path, overrides, words, capsys, monkeypatch):
    monkeypatch.chdir(ROOT)
    rc = run_stage(campaign_stage.main, description="",
                   argv=[*overrides, "campaign.worlds=1", f"campaign.out_dir={tmp_path / 'camp'}"])
    err = capsys.readouterr().err
    assert rc == 2 and words in err and "Traceback" not in err, err
    assert not (tmp_path / "camp").exists()


def test_the_command_in_a_deleted_folder_or_with_a_path_of_the_working_folder(tmp_path, capsys, monkeypatch):
    import sys

    from nanosysid import cli

    gone = tmp_path / "gone"
    gone.mkdir()
    monkeypatch.chdir(gone)
    gone.rmdir()
    assert cli.main(["split"]) == 2
    assert "the working folder no longer exists" in capsys.readouterr().err
    # a relative folder of the user's working folder is read there, not in the project
    (tmp_path / "mine").mkdir()
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", list(sys.argv))
    monkeypatch.setattr(sys, "path", list(sys.path))
    assert cli.main(["split", "data.flights_dir=mine", f"paths.split={tmp_path / 'split'}"]) == 2
    err = capsys.readouterr().err
    assert f"data.flights_dir=mine is {tmp_path / 'mine'}" in err and f"{tmp_path / 'mine'}: no flight CSV files" in err


def test_a_config_groups_option_chosen_on_a_stages_command_line(monkeypatch):
    import yaml as _yaml

    from nanosysid.errors import ConfigError

    monkeypatch.chdir(ROOT)
    cfg = config.load_params(["topics@preprocess.topics=crazyflie"])
    expected = _yaml.safe_load((ROOT / "conf" / "topics" / "crazyflie.yaml").read_text())
    assert config.OmegaConf.to_container(cfg.preprocess.topics) == expected
    with pytest.raises(ConfigError, match=r"topics@preprocess.topics=myrig: no option 'myrig' in conf/topics/ "
                                          r"\(known: crazyflie\)"):
        config.load_params(["topics@preprocess.topics=myrig"])
