"""Time of the discovery workflow on the default dataset (limit: 5 minutes), split into the
search itself and the analysis of where the models disagree, against one evaluation of the
nominal model in the same run."""

from __future__ import annotations

import time

from omegaconf import OmegaConf

from nanosysid import discover, protocol
from nanosysid.config import load_params
from nanosysid.discover.model import AugmentedPredictor, AugmentedStep
from nanosysid.predictors import build_from_options
from nanosysid.vehicle import Vehicle


def main() -> dict[str, float]:
    cfg = load_params()
    bench = protocol.load(cfg.paths.split)
    oracle = build_from_options(OmegaConf.to_container(cfg.discover.oracle, resolve=True)) if cfg.discover.oracle else None
    t0 = time.perf_counter()
    protocol.evaluate(AugmentedPredictor(AugmentedStep(Vehicle())), bench.test)
    t_eval = time.perf_counter() - t0
    t0 = time.perf_counter()
    discover.run(bench.train, bench.test, oracle=oracle, analysis=False)
    t_search = time.perf_counter() - t0
    t0 = time.perf_counter()
    r = discover.run(bench.train, bench.test, oracle=oracle, analysis=True)
    t_full = time.perf_counter() - t0
    print(f"{len(bench.train)} training and {len(bench.test)} test flights; named: {r.name}")
    print(f"one evaluation of the nominal model: {t_eval:.1f} s")
    print(f"search, fit and scores:              {t_search:.1f} s ({t_search / t_eval:.1f}x one evaluation)")
    print(f"with the disagreement analysis:      {t_full:.1f} s (limit 300 s)")
    return {"evaluation_s": t_eval, "search_s": t_search, "search_over_evaluation": t_search / t_eval,
            "with_analysis_s": t_full}


if __name__ == "__main__":
    main()
