"""make bench: every benchmark in one process, their figures recorded in ``reports/bench.json``.

The record holds the machine (CPU model, cores, the pinned thread count, torch and Python
versions), and for each benchmark its figures: times in seconds and the ratios against the
reference each measures in the same run, and each time as a ratio against the previous record's
where that was taken on the same machine. No date: the same figures give the same bytes.
``python -m nanosysid.report.readme --sections bench`` puts them into the README.

``benchmarks/run.py NAME ...`` runs only those; the record keeps the other benchmarks' figures
when it was taken on the same machine, and is started afresh otherwise.
"""

from __future__ import annotations

from nanosysid import numerics

numerics.pin()  # the code paths the stages run, before torch and numpy are loaded

import argparse  # noqa: E402
import importlib  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

from nanosysid.report.runtimes import machine  # noqa: E402

BENCHMARKS = ("simulate_speed", "simulate_batch", "data_pipeline_speed", "evaluate_speed", "oracle_speed", "train_threads",
              "pinned_level", "discover_speed", "heldout_speed", "blas_threads", "visualize_speed", "busy_paths",
              "test_suite")
FORMAT = "nanosysid-bench-1"


def _round(v):
    return float(f"{v:.3g}") if isinstance(v, float) else v


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def against_previous(previous: dict, figures: dict) -> dict:
    """Each time of ``figures`` (a key ending in ``_s``) as a ratio to the same time in ``previous``,
    the last record's figures of that benchmark on the same machine: below 1, faster now."""
    return {k: v / previous[k] for k, v in figures.items()
            if k.endswith("_s") and _number(v) and _number(previous.get(k)) and previous[k] > 0}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("reports/bench.json"))
    p.add_argument("names", nargs="*", default=list(BENCHMARKS), metavar="NAME", help=f"of {', '.join(BENCHMARKS)}")
    a = p.parse_args(argv)
    unknown = sorted(set(a.names) - set(BENCHMARKS))
    if unknown:
        p.error(f"unknown benchmark {', '.join(unknown)}: choose from {', '.join(BENCHMARKS)}")
    sys.path.insert(0, str(Path(__file__).parent))
    record = {"format": FORMAT, "machine": machine(), "benchmarks": {}}
    old = json.loads(a.out.read_text()) if a.out.exists() else {}
    same = old.get("format") == FORMAT and old.get("machine") == record["machine"]
    previous = old["benchmarks"] if same else {}
    if set(a.names) < set(BENCHMARKS):
        record["benchmarks"] = dict(previous)
    for name in a.names:
        print(f"== benchmarks/{name}.py", flush=True)
        module = importlib.import_module(name)
        figures = {k: _round(v) for k, v in module.main().items()}
        entry = {"about": module.__doc__.strip().split("\n\n")[0].replace("\n", " "), "figures": figures}
        ratios = against_previous(previous.get(name, {}).get("figures", {}), figures)
        if ratios:
            entry["against_previous"] = {k: _round(v) for k, v in ratios.items()}
        record["benchmarks"][name] = entry
    record["benchmarks"] = {k: record["benchmarks"][k] for k in BENCHMARKS if k in record["benchmarks"]}
    from nanosysid.dataio import atomic_file

    with atomic_file(a.out, replace=True) as tmp:  # the record is rewritten by every run (a committed file)
        tmp.write_text(json.dumps(record, indent=1, allow_nan=False) + "\n")
    print(f"{a.out}: written")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
