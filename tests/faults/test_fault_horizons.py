"""A horizon other than the paper's 50 is a legal quick run: the tables show the horizons within
it instead of dying half-written, and scores of different horizons, whose sums are not
comparable, are refused before anything is written."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nanosysid.errors import DataError
from nanosysid.protocol import Scores
from nanosysid.report import tables

CLASS = "wrong result written"


def scores(H, level=1.0):
    return Scores(mae={k: level * np.arange(1, H + 1, dtype=float) for k in ("p", "v", "R", "w")}, n_windows=10)


@pytest.mark.parametrize("H", [1, 5, 20, 49])
@pytest.mark.parametrize("table", ["md", "tex"])
def test_a_short_horizon_shows_the_table_horizons_within_it(H, table):
    rows = {"physics": scores(H), "lstm": scores(H, 2.0)}
    text = (tables.results_table_md if table == "md" else tables.results_table_tex)(rows)
    shown = [h for h in (1, 10, 50) if h <= H]
    for h in (1, 10, 50):
        assert ((f"h={h} [" in text) if table == "md" else (f"$h{{=}}{h}$" in text)) == (h in shown), (h, text)
    # the sum over the horizon: 1 + 2 + .. + H for physics
    assert f"{H * (H + 1) / 2:.4f}" in text


@pytest.mark.parametrize("table", ["md", "tex"])
def test_scores_of_different_horizons_are_refused(table):
    rows = {"physics": scores(50), "lstm": scores(20)}
    with pytest.raises(DataError, match="physics H = 50, lstm H = 20; evaluate every model at one eval.horizon"):
        (tables.results_table_md if table == "md" else tables.results_table_tex)(rows)


def test_loading_evaluations_of_different_horizons_is_refused_before_any_figure(tmp_path):
    for name, H in (("physics", 50), ("lstm", 20), ("naive", 50)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "scores.json").write_text(json.dumps({"model": name, **scores(H).to_dict()}))
    with pytest.raises(DataError, match="lstm H = 20"):
        tables.load_scores(tmp_path, ["physics", "lstm", "naive"])
    assert set(tables.load_scores(tmp_path, ["physics", "naive"])) == {"physics", "naive"}
