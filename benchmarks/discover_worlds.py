"""Discovery on many hidden worlds (short flights): recall per world effect and strength,
precision of the "named" verdicts, clean and out-of-library worlds, the share of the
nominal-to-oracle gap closed, and the plain SINDy discrepancy model on the same worlds.

``python benchmarks/discover_worlds.py --worlds 60 --workers 2 --out reports/discover_worlds.json``
"""

from __future__ import annotations

from nanosysid import numerics

numerics.pin()

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from nanosysid import worlds  # noqa: E402


def _pct(x) -> str:
    return "–" if x is None else f"{100 * x:.0f} %"


def report(summary: dict) -> str:
    L = [f"{summary['worlds']} worlds, {summary['failed']} where the augmented model diverged on the test flight"]
    L.append("recall (named or ambiguous with a describing entry) where the effect moves the nominal SimErr > 10 %:")
    for e, bins in sorted(summary["recall_counts"].items()):
        cells = [f"{b}: {c['hit_relevant']}/{c['relevant']} (all {c['hit']}/{c['worlds']})" for b, c in sorted(bins.items())]
        L.append(f"  {e:16s} " + "; ".join(cells))
    L.append(f"named verdicts: {summary['named']}, precision {_pct(summary['precision'])}")
    L.append(f"clean worlds: {summary['clean_worlds']}, without a finding {_pct(summary['clean_without_finding'])}")
    L.append(f"out-of-library worlds: {summary['out_of_library_worlds']}, without a false name "
             f"{_pct(summary['out_of_library_without_false_name'])}")
    L.append(f"worlds with a state-dependent effect: {summary['state_worlds']}, half the gap closed in "
             f"{_pct(summary['half_gap_closed'])} (median {_pct(summary['gap_closed_median'])})")
    L.append(f"plain SINDy: median gap closed {_pct(summary['sindy_gap_closed_median'])}, "
             f"{summary['sindy_terms_mean']:.1f} terms on average; discovery closes more in {_pct(summary['beats_sindy'])}")
    return "\n".join(L)


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--worlds", type=int, default=60)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--out", type=Path, default=None, help="also write the rows and the summary as JSON")
    a = p.parse_args(argv)
    t0 = time.perf_counter()
    rows = worlds.check(worlds.draw(a.worlds, a.seed), workers=a.workers)
    summary = worlds.summarize(rows)
    print(report(summary))
    print(f"{time.perf_counter() - t0:.0f} s")
    if a.out:
        a.out.write_text(json.dumps({"summary": summary, "worlds": rows}, indent=1) + "\n")
    return {"worlds_s": time.perf_counter() - t0, **{k: v for k, v in summary.items() if isinstance(v, (int, float))}}


if __name__ == "__main__":
    main()
