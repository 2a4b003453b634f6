"""The initialization-window track's report: every model on the track's windows, beside the paper's
best row of each column, and the data's limit of the angular velocity given the window's history."""

from __future__ import annotations

from typing import Mapping, Sequence

from nanosysid.metrics import QUANTITIES
from nanosysid.protocol import Scores
from nanosysid.report.paper import PAPER_RESULTS

__all__ = ["paper_best", "beats_paper", "window_markdown"]

_LABEL = {"p": "position", "v": "velocity", "R": "orientation", "w": "angular velocity"}


def paper_best() -> dict[str, tuple[str, float]]:
    """The paper's best row of each SimErr column: ``{quantity: (model, SimErr)}``."""
    out = {}
    for q in QUANTITIES:
        name = min(PAPER_RESULTS, key=lambda m: PAPER_RESULTS[m][q][3])
        out[q] = (name, PAPER_RESULTS[name][q][3])
    return out


def beats_paper(simerr: Mapping[str, float]) -> dict[str, bool]:
    """Per quantity, whether ``simerr`` is below the paper's best row of that column."""
    best = paper_best()
    return {q: simerr[q] < best[q][1] for q in QUANTITIES}


def _g(x: float) -> str:
    return f"{x:.4g}"


def _row(label: str, simerr: Mapping[str, float | None]) -> str:
    return f"| {label} | " + " | ".join("–" if simerr.get(q) is None else _g(simerr[q]) for q in QUANTITIES) + " |"


def window_markdown(*, init: int, horizon: int, scores: Mapping[str, Scores], rate_map: Mapping[str, Scores],
                    hold: Mapping[str, Scores], features: tuple[str, ...], base: str, source: str,
                    left_out: Sequence[str] = ()) -> str:
    """The report. ``scores``: each model on the test flights' track windows; ``rate_map`` and
    ``hold``: the rate map and holding the rate, under the keys ``in_sample`` and ``held_out``
    (training flights) and ``test``; ``base``: the model whose position and velocity the rate map
    keeps; ``source``: the data, in words; ``left_out``: flights too short for a window. Without
    ``rate_map["held_out"]`` (one reference trajectory among the training flights) the report says
    so."""
    best = paper_best()
    n_test = next(iter(scores.values())).n_windows
    lines = [
        f"# The initialization-window track (W = {init} samples)",
        "",
        f"The paper's protocol gives a predictor the state at a window's start and the rotor speeds over the "
        f"horizon. The field's loader for this dataset (nonlinear_benchmarks' NanoDrone) also gives the {init} "
        f"samples before the start (a state-initialization window). Here every predictor may use them; a window "
        f"starts {init} samples into a flight at the earliest, so this track scores {n_test} windows of the test "
        f"flights ({source}), fewer than the paper's protocol: its figures stand apart from the paper's table, and the "
        "models are compared on the same windows here." + (
            f" Flights too short for a window and its history, left out: {', '.join(left_out)}." if left_out else ""),
        "",
        f"| SimErr on the test flights, W = {init} | position | velocity | orientation | angular velocity |",
        "|---|---|---|---|---|",
    ]
    for name, s in scores.items():
        lines.append(_row(f"`{name}`", s.simerr))
    lines.append(_row(f"`{base}` with the window's rate map (the data's limit of ω and R)",
                      {q: rate_map["test"].simerr[q] for q in ("R", "w")}))
    lines.append(_row("the paper's best row of each column (its protocol, every window)",
                      {q: best[q][1] for q in QUANTITIES}))
    lines += ["", "The paper's best rows: " + "; ".join(f"{_LABEL[q]} `{best[q][0]}` {_g(best[q][1])}"
                                                        for q in QUANTITIES) + ".", ""]
    for name, s in scores.items():
        won = beats_paper(s.simerr)
        if all(won.values()):
            verdict = "below the paper's best row in every column"
        else:
            verdict = "not below the paper's best row in " + ", ".join(_LABEL[q] for q in QUANTITIES if not won[q])
        lines.append(f"- `{name}`: {verdict}.")
    hold_test = hold["test"].simerr["w"]
    lines += [
        "",
        f"A window's first sample is at least {init} samples into its flight, so the take-off's first half second is "
        f"never scored here: holding the rate (dω/dt = 0) scores ω {_g(hold_test)} on this track's windows, and the "
        "paper's figures were taken over every window. What the window itself buys a model is its difference from the "
        "same model without it, on the same windows: for every model above but the rate map, none (they read the "
        "start's state only).",
        "",
        "## What the window can buy the angular velocity",
        "",
        "The data's limit given the window: per horizon step and body axis, a least-squares map from what the window "
        "shows and the horizon's rotor speeds to the change of the rate, fitted on the training flights. Its features:",
        "",
        *(f"- {f}" for f in features),
        "",
        "The orientation is integrated from the predicted rates. A function of these signals that the map cannot "
        "fit, held out, no linear model of them can. SimErr of the orientation and the angular velocity, holding the "
        "rate against the rate map:",
        "",
        "| flights | windows | orientation, ω held | orientation, rate map | ω, held | ω, rate map |",
        "|---|---|---|---|---|---|",
    ]
    labels = {"in_sample": "training flights, the map fitted on all of them",
              "held_out": "training flights, each reference's runs by the map fitted on the other references'",
              "test": "test flights"}
    for key, label in labels.items():
        if key not in rate_map:
            lines.append(f"| {label} | – | – | – | – | – |")
            continue
        h, m = hold[key].simerr, rate_map[key].simerr
        lines.append(f"| {label} | {hold[key].n_windows} | {_g(h['R'])} | {_g(m['R'])} | {_g(h['w'])} | "
                     f"{_g(m['w'])} |")
    lines += ["", "On each test flight, ω:", "", "| test flight | ω held | rate map | change |", "|---|---|---|---|"]
    for name, s in rate_map["test"].per_flight.items():
        h = hold["test"].per_flight[name].simerr["w"]
        lines.append(f"| {name} | {_g(h)} | {_g(s.simerr['w'])} | {100 * (s.simerr['w'] / h - 1):+.1f} % |")
    gain = {k: rate_map[k].simerr["w"] / hold[k].simerr["w"] - 1 for k in labels if k in rate_map}
    if "held_out" not in gain:
        lines += ["", "The training flights fly one reference trajectory: the map cannot be scored on a manoeuvre "
                  "it was not fitted on before the test flights."]
    lines += ["", _conclusion(gain), ""]
    return "\n".join(lines)


def _conclusion(gain: Mapping[str, float]) -> str:
    pct = {k: f"{100 * v:+.1f} %" for k, v in gain.items()}
    held = "held_out" in gain
    if gain["test"] < 0 and (not held or gain["held_out"] < 0):
        return (f"**The window buys the angular velocity something**: against holding the rate, the rate map changes "
                f"ω's SimErr by {pct['test']} on the test flights"
                + (f" and {pct['held_out']} on training flights of a reference it was not fitted on." if held else "."))
    if not held:
        why = "with one reference among the training flights, nothing here tells what carries over to another"
    elif gain["held_out"] < 0:
        why = ("on training flights of a reference it was not fitted on it still gains, so what it learns carries "
               "over between the training manoeuvres but not to the test flights' manoeuvre")
    else:
        why = ("it loses already on training flights of a reference it was not fitted on: what it learns of the "
               "torque residual belongs to the manoeuvres it was fitted on")
    return (f"**What stops it**: against holding the rate, the map changes the ω SimErr by {pct['in_sample']} on the "
            "training flights it was fitted on, "
            + (f"{pct['held_out']} on training flights of a reference left out of its fit, " if held else "")
            + f"and {pct['test']} on the test flights: {why}. No linear function of the window and the rotor "
            "speeds, integrated as the torque equation is, beats holding the rate on the test flights; a model of "
            "the torque residual that would has to carry over to a manoeuvre it was not fitted on.")
