"""The dataset and the benchmark's results beside the paper's real flights.

Three comparisons, each a table and a verdict: the trajectory statistics (within a tolerance of
the paper's table), the naive and physics rows at h = 10 and 50 for position and velocity
(within a factor of the paper's: the one place where a simulated world can be calibrated
against real flight), and the *pattern* of the results: each learned model's SimErr over the
physics model's, beside the paper's ratio, and the best model of each SimErr column where the
paper's margin is large enough to be a finding rather than noise.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

from nanosysid.protocol import Scores
from nanosysid.metrics import QUANTITIES

__all__ = ["PAPER_COST", "PAPER_STATS", "PAPER_RESULTS", "PAPER_MODELS", "PAPER_IDENTIFIED", "Comparison", "compare_results",
           "compare_identification", "compare_world", "results_markdown", "identification_markdown"]

# The paper's table of model costs: parameters [k], compute [kFLOPs], T_inf on the STM32 [ms].
PAPER_COST = {
    "naive": {"params_k": None, "kflops": None, "t_inf_ms": None},
    "physics": {"params_k": None, "kflops": 0.8, "t_inf_ms": 1.79},
    "residual": {"params_k": 18.5, "kflops": 18.2, "t_inf_ms": 1.03},
    "phys_res": {"params_k": 18.5, "kflops": 18.2, "t_inf_ms": 2.82},
    "lstm": {"params_k": 24.7, "kflops": 25.1, "t_inf_ms": 2.09},
}


# Paper, table "Benchmark statistics for real quadrotor trajectories" (averaged across runs).
PAPER_STATS = {
    "square": {"duration": 19.00, "v_mean": 0.83, "v_max": 2.60, "a_max": 12.53, "tilt_max": 42.95},
    "random": {"duration": 60.00, "v_mean": 1.11, "v_max": 2.69, "a_max": 8.30, "tilt_max": 43.23},
    "melon": {"duration": 65.00, "v_mean": 1.44, "v_max": 3.06, "a_max": 10.91, "tilt_max": 56.07},
    "chirp": {"duration": 60.00, "v_mean": 0.88, "v_max": 3.02, "a_max": 10.13, "tilt_max": 62.69},
}

# The paper's table of numerical performance (Melon test flights): MAE at h = 1, 10, 50 and the
# SimErr (sum over h = 1..50), per quantity, for its five models (our names).
PAPER_RESULTS: dict[str, dict[str, tuple[float, float, float, float]]] = {
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
PAPER_MODELS = tuple(PAPER_RESULTS)
# The paper's identified rotor coefficients (least squares on its closed-loop training flights).
PAPER_IDENTIFIED = {"k_f": 3.72e-8, "k_m": 7.73e-11}
_HORIZONS = (1, 10, 50)
_LABEL = {"p": "p", "v": "v", "R": "R", "w": "ω"}


@dataclass
class Comparison:
    """The figures of the comparison and whether each criterion holds.

    Attributes:
        rows: ``(model, quantity, h) -> (ours, paper)`` for the naive and physics rows at h = 10, 50.
        ratios: ``(model, quantity) -> (ours, paper)``: the model's SimErr over physics'.
        best: ``quantity -> (ours, paper, paper's margin)``: the model with the least SimErr.
        checks: criterion -> whether it holds.
        world: ``(model, quantity) -> (ratio, verdict)``: the default world's ratio beside the
            real flights' ``ratios`` (:func:`compare_world`).
    """

    rows: dict[tuple[str, str, int], tuple[float, float]] = field(default_factory=dict)
    ratios: dict[tuple[str, str], tuple[float, float]] = field(default_factory=dict)
    best: dict[str, tuple[str, str, float]] = field(default_factory=dict)
    checks: dict[str, bool] = field(default_factory=dict)
    identification: dict[str, Any] = field(default_factory=dict)
    world: dict[tuple[str, str], tuple[float, str]] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "rows": [{"model": m, "quantity": k, "h": h, "ours": a, "paper": b} for (m, k, h), (a, b) in self.rows.items()],
            "ratios": [{"model": m, "quantity": k, "ours": a, "paper": b} for (m, k), (a, b) in self.ratios.items()],
            "best": {k: {"ours": a, "paper": b, "paper_margin": c} for k, (a, b, c) in self.best.items()},
            "checks": self.checks,
            "identification": self.identification,
            **({"world": [{"model": m, "quantity": k, "ratio": a, "verdict": v} for (m, k), (a, v) in self.world.items()]}
               if self.world else {}),
        }


def _best(simerr: Mapping[str, float]) -> tuple[str, float]:
    """The model with the least value, and its margin: the runner-up's value over it, minus 1."""
    order = sorted(simerr, key=simerr.get)
    return order[0], simerr[order[1]] / simerr[order[0]] - 1


def compare_results(scores: Mapping[str, Scores], *, factor: float = 1.5, ratio_tolerance: float = 0.25,
                    margin: float = 0.10, ratio_models: Sequence[str] = ("residual", "phys_res", "lstm")) -> Comparison:
    """Our results against the paper's.

    Args:
        scores: Scores of (some of) the paper's five models, by our names.
        factor: The naive and physics rows at h = 10, 50 (p, v) must be within this factor.
        ratio_tolerance: Each of ``ratio_models``' SimErr over physics' must be within this
            relative distance of the paper's ratio, in every column.
        margin: Where the paper's best model of a SimErr column leads by more than this, ours
            must be the same.
    """
    c = Comparison()
    for m in ("naive", "physics"):
        if m in scores:
            for k in ("p", "v"):
                for h in (10, 50):
                    c.rows[(m, k, h)] = (float(scores[m].mae[k][h - 1]), PAPER_RESULTS[m][k][_HORIZONS.index(h)])
    if c.rows:
        c.checks[f"naive and physics rows within x{factor:g}"] = all(
            1 / factor <= a / b <= factor for a, b in c.rows.values())
    if "physics" in scores:
        for m in PAPER_MODELS:
            if m in scores and m not in ("naive", "physics"):
                for k in QUANTITIES:
                    c.ratios[(m, k)] = (scores[m].simerr[k] / scores["physics"].simerr[k],
                                        PAPER_RESULTS[m][k][3] / PAPER_RESULTS["physics"][k][3])
        for m in ratio_models:
            if (m, "p") in c.ratios:
                c.checks[f"{m} / physics within {ratio_tolerance:.0%} of the paper's ratio"] = all(
                    abs(c.ratios[(m, k)][0] / c.ratios[(m, k)][1] - 1) <= ratio_tolerance for k in QUANTITIES)
    if all(m in scores for m in PAPER_MODELS):
        for k in QUANTITIES:
            ours, _ = _best({m: scores[m].simerr[k] for m in PAPER_MODELS})
            paper, paper_margin = _best({m: PAPER_RESULTS[m][k][3] for m in PAPER_MODELS})
            c.best[k] = (ours, paper, paper_margin)
        c.checks[f"best model of each SimErr column as the paper's where its margin is over {margin:.0%}"] = all(
            ours == paper for ours, paper, pm in c.best.values() if pm > margin)
    return c


# A verdict on one of the default world's ratios, beside the paper's and the real flights'
WITHIN, AS_REAL, OFF = "within", "as the real flights", "off"


def compare_world(real: Comparison, world: Mapping[tuple[str, str], float], *, ratio_tolerance: float = 0.25) -> None:
    """The default world's pattern beside the paper's and the real flights' (``real``: the
    comparison on the paper's own flights), into ``real.world`` and a check.

    A simulated world stands for the rig: where the pipeline on the paper's own flights misses the
    paper's ratio, the world is expected to miss it the same way, not to reproduce the paper. Each
    world ratio is within ``ratio_tolerance`` of the paper's, or misses it as the real flights do:
    within ``ratio_tolerance`` of the real flights' ratio (which puts a miss on the same side of the
    paper's as theirs); else it is off.

    Args:
        real: The comparison on the real flights (its ``ratios`` filled).
        world: ``(model, quantity) -> SimErr ratio`` on the default world's test flights.
    """
    for key, (ours, paper) in real.ratios.items():
        if key not in world:
            continue
        w = float(world[key])
        if abs(w / paper - 1) <= ratio_tolerance:
            verdict = WITHIN
        elif abs(w / ours - 1) <= ratio_tolerance:
            verdict = AS_REAL
        else:
            verdict = OFF
        real.world[key] = (w, verdict)
    if real.world:
        real.checks[f"the default world's ratios within {ratio_tolerance:.0%} of the paper's, or missing it as the "
                    "real flights do"] = all(v != OFF for _, v in real.world.values())


def _within(fit: Mapping[str, Any], truth: float) -> bool:
    ci = fit.get("ci95")
    return ci is not None and ci[0] <= truth <= ci[1]


def compare_identification(c: Comparison, params: Mapping[str, Any], *, k_f: float, k_m: float,
                           k_f_thrust: float | None = None, paper_tolerance: float = 0.25,
                           k_f_tolerance: float = 0.01, k_m_tolerance: float = 0.05) -> None:
    """The identified k_F and k_M (``params.json``) against nature's and the paper's, into ``c``.

    Args:
        params: The identify stage's result.
        k_f, k_m: Nature's coefficients.
        k_f_thrust: The one k_F nature's own thrust gives over the training flights (noise-free
            thrust on noise-free sum Omega^2): with rotors a few per cent apart, the collective
            coefficient of a one-k_F model is this, not the rotors' mean.
        paper_tolerance: The paper's method on our training flights must give the paper's k_M
            within this relative distance: the world reproduces the paper's identification,
            bias included.
    """
    paper_fit = params.get("yaw_fit_paper_method", params["yaw_fit"])
    ident = {"k_f": {"nature": k_f, "nature_thrust": k_f_thrust, "identified": params["k_f"],
                     "fit": params["thrust_fit"]},
             "k_m": {"nature": k_m, "identified": params["k_m"], "fit": params["yaw_fit"],
                     "paper_method": paper_fit["coef"], "paper_method_fit": paper_fit,
                     "paper": PAPER_IDENTIFIED["k_m"]}}
    c.identification = ident
    c.checks[f"the paper's method on our training flights gives the paper's k_M within {paper_tolerance:.0%}"] = (
        abs(paper_fit["coef"] / PAPER_IDENTIFIED["k_m"] - 1) <= paper_tolerance)
    target = k_f if k_f_thrust is None else k_f_thrust
    c.checks[f"k_F within {k_f_tolerance:.0%} of nature's, its interval covering nature's thrust per sum Omega^2"] = (
        abs(params["k_f"] / k_f - 1) <= k_f_tolerance and _within(params["thrust_fit"], target))
    c.checks[f"k_M within {k_m_tolerance:.0%} of nature's, its interval covering it"] = (
        abs(params["k_m"] / k_m - 1) <= k_m_tolerance and _within(params["yaw_fit"], k_m))


def identification_markdown(c: Comparison) -> str:
    """The identification against nature's and the paper's numbers, as a Markdown section."""
    if not c.identification:
        return ""
    f, m = c.identification["k_f"], c.identification["k_m"]

    def ci(fit):
        return "–" if fit.get("ci95") is None else f"{fit['ci95'][0]:.4g} to {fit['ci95'][1]:.4g}"

    L = ["## Identification against nature", "",
         "The rotor coefficients the identify stage gives (`models/physics/params.json`), their 95 % intervals (from "
         "the flights, or the calibration flights' blocks, as independent repeats), and nature's. The paper's method "
         "(least squares on the closed-loop training flights) is biased towards zero for k_M: the yaw loop cancels the "
         "yaw disturbances through the very rotor-speed difference the fit regresses on. On this world the paper's method "
         f"gives a k_M {abs(m['paper_method'] / m['paper'] - 1):.0%} "
         f"{'below' if m['paper_method'] < m['paper'] else 'above'} the paper's, while the world's truth is the thrust "
         "stands' (5.69 mm of yaw torque per newton of thrust).", "",
         "| coefficient | estimator | estimate | 95 % interval | nature | error |", "|---|---|---|---|---|---|",
         f"| k_F [N s²/rad²] | {f['fit']['estimator']} | {f['identified']:.4g} | {ci(f['fit'])} | {f['nature']:.4g}"
         + ("" if f["nature_thrust"] is None else f" (its thrust per ΣΩ² on these flights: {f['nature_thrust']:.4g})")
         + f" | {f['identified'] / f['nature'] - 1:+.2%} |",
         f"| k_M [N m s²/rad²] | {m['fit']['estimator']} | {m['identified']:.4g} | {ci(m['fit'])} | {m['nature']:.4g} | "
         f"{m['identified'] / m['nature'] - 1:+.1%} |",
         f"| k_M, the paper's method | {m['paper_method_fit']['estimator']} | {m['paper_method']:.4g} | "
         f"{ci(m['paper_method_fit'])} | {m['nature']:.4g} | {m['paper_method'] / m['nature'] - 1:+.1%} |",
         f"| k_M, the paper's table | least squares on the real closed-loop flights | {m['paper']:.4g} | – | – | "
         f"ours by its method {m['paper_method'] / m['paper'] - 1:+.1%} |", ""]
    jz = m["fit"].get("inertia_z_range")
    if jz and m["fit"].get("ci95_inertia"):
        lo, hi = m["fit"]["ci95_inertia"]
        L += [f"The flights identify k_M / J_z, not k_M: every yaw coefficient scales with the yaw inertia the gyro's "
              f"torque is read with. With J_z anywhere in the sources' {jz[0]:.4g} to {jz[1]:.4g} kg m² "
              f"(`identify.inertia_z_range`), k_M's 95 % interval is {lo:.4g} to {hi:.4g}"
              f" ({'covering' if lo <= m['nature'] <= hi else 'missing'} nature's).", ""]
    return "\n".join(L)


def _mark(ok: bool) -> str:
    return "✓" if ok else "✗"


_WORLD_MARK = {WITHIN: "✓", AS_REAL: "≈", OFF: "✗"}


def results_markdown(c: Comparison, *, factor: float = 1.5, ratio_tolerance: float = 0.25, margin: float = 0.10) -> str:
    """The comparison as Markdown sections (no heading of the document's own)."""
    L: list[str] = []
    if c.rows:
        L += ["## The naive and physics rows against the paper's", "",
              f"MAE at h = 10 and 50 (0.1 and 0.5 s) on the test flights: ours / paper (ratio); a ratio outside "
              f"1/{factor:g} .. {factor:g} is marked ✗.", "",
              "| model | p h=10 [m] | p h=50 [m] | v h=10 [m/s] | v h=50 [m/s] |", "|---|---|---|---|---|"]
        for m in ("naive", "physics"):
            cells = []
            for k in ("p", "v"):
                for h in (10, 50):
                    if (m, k, h) in c.rows:
                        a, b = c.rows[(m, k, h)]
                        cells.append(f"{a:.4f} / {b:.4f} ({a / b:.2f}{'' if 1 / factor <= a / b <= factor else ' ✗'})")
            if cells:
                L.append(f"| {m} | " + " | ".join(cells) + " |")
        L.append("")
    if c.ratios:
        L += ["## The pattern of the results: SimErr over the physics model's", "",
              "Each learned model's SimErr (sum of the MAE over h = 1..50) divided by the physics model's, per "
              "quantity: on the paper's real flights the learned models barely beat physics, because real flight has "
              f"effects no model of the state can know. Ours beside the paper's; ✓ where ours is within "
              f"{ratio_tolerance:.0%} of the paper's ratio.", "",
              "| SimErr ratio | " + " | ".join(_LABEL[k] for k in QUANTITIES) + " |",
              "|---|" + "---|" * len(QUANTITIES)]
        for m in dict.fromkeys(m for m, _ in c.ratios):
            L.append(f"| {m} / physics, paper | " + " | ".join(f"{c.ratios[(m, k)][1]:.2f}" for k in QUANTITIES) + " |")
            L.append(f"| {m} / physics, ours | " + " | ".join(
                f"{c.ratios[(m, k)][0]:.2f} {_mark(abs(c.ratios[(m, k)][0] / c.ratios[(m, k)][1] - 1) <= ratio_tolerance)}"
                for k in QUANTITIES) + " |")
            if all((m, k) in c.world for k in QUANTITIES):
                L.append(f"| {m} / physics, the default world | " + " | ".join(
                    f"{c.world[(m, k)][0]:.2f} {_WORLD_MARK[c.world[(m, k)][1]]}" for k in QUANTITIES) + " |")
        if c.world:
            L += ["", f"The default world's rows (reports/sim/stats.md): ✓ within {ratio_tolerance:.0%} of the "
                  f"paper's ratio; ≈ missing it as the real flights do (within {ratio_tolerance:.0%} of the real "
                  "flights' ratio); ✗ neither."]
        L.append("")
    if c.best:
        L += ["## The best model of each SimErr column", "",
              f"Among the paper's five models. Where the paper's best leads the runner-up by more than {margin:.0%} "
              "it is a finding and ours must be the same; below that the paper's order is within its noise.", "",
              "| quantity | paper's best | its margin | ours | must match |", "|---|---|---|---|---|"]
        for k, (ours, paper, pm) in c.best.items():
            must = pm > margin
            L.append(f"| {_LABEL[k]} | {paper} | {pm:.1%} | {ours} | "
                     f"{(_mark(ours == paper) if must else 'no')} |")
        L.append("")
    if c.checks:
        L += ["## Verdict", ""] + [f"- {_mark(ok)} {name}" for name, ok in c.checks.items()] + [""]
    return "\n".join(L)

