"""Time of the oracle's evaluation on the test flights (the `evaluate@oracle` stage's work), its
derivative compiled (the product's setting) against the same oracle run eagerly, in the same run."""

from __future__ import annotations

import time

import numpy as np
from omegaconf import OmegaConf

from nanosysid import protocol
from nanosysid.config import load_params
from nanosysid.predictors import build_from_options


def main() -> dict[str, float]:
    cfg = load_params()
    H = int(cfg.eval.horizon)
    bench = protocol.load(cfg.paths.split, horizon=H)
    options = OmegaConf.to_container(cfg.models.oracle, resolve=True)
    times, scores = {}, {}
    # compiled first (its first call compiles, as in the stage), eager second, compiled again
    for key, compile in (("compiled_first", True), ("eager", False), ("compiled", True)):
        oracle = build_from_options({**options, "compile": compile})
        t0 = time.perf_counter()
        scores[key] = protocol.evaluate(oracle, bench.test, horizon=H)
        times[key] = time.perf_counter() - t0
    same = all(np.array_equal(scores["eager"].mae[q], scores["compiled"].mae[q]) for q in scores["eager"].mae)
    windows = scores["eager"].n_windows
    print(f"{len(bench.test)} test flights, {windows} windows of {H} steps")
    print(f"compiled, first call: {times['compiled_first']:.2f} s (with the compile)")
    print(f"compiled:             {times['compiled']:.2f} s")
    print(f"eager:                {times['eager']:.2f} s ({times['eager'] / times['compiled']:.2f}x)")
    print(f"same scores, to the bit: {'yes' if same else 'no'}")
    return {"windows": windows, "compiled_first_s": times["compiled_first"], "compiled_s": times["compiled"],
            "eager_s": times["eager"], "eager_over_compiled": times["eager"] / times["compiled"],
            "same_scores": "yes" if same else "no"}


if __name__ == "__main__":
    main()
