"""Training of the three learned models with their own settings (`models.<name>.train`) at the
two pinned code-path levels (`nanosysid.numerics`): the AVX2 one ("v3"), which the train stage
takes on a CPU that has it, against the x86-64-v2 one that every other stage runs ("v2", and the
train stage's under `NANOSYSID_CPU_LEVEL=v2`), and the AVX2 level with MKL's COMPATIBLE branch of
conditional numerical reproducibility (the one that is the same on Intel and AMD CPUs, where the
train stage's AVX2 branch is Intel's only), each in a process of its own, in the same run: seconds
per epoch once compiled (`benchmarks/train_threads.py`'s ``per_epoch``)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

MODELS = ("residual", "phys_res", "lstm")
ROOT = Path(__file__).resolve().parents[1]

# one level's fits (argv: the level, MKL's branch or "-" for the level's own, the models), in a
# process that pins its code paths before torch is loaded, as a stage does
CHILD = """
import sys
from nanosysid import numerics
if sys.argv[2] != "-":
    numerics.PINNED_V3["MKL_CBWR"] = sys.argv[2]
numerics.pin(sys.argv[1])
import json, tempfile
from pathlib import Path
sys.path.insert(0, "benchmarks")  # train_threads' per_epoch, as benchmarks/run.py finds it
from nanosysid.config import load_params
from train_threads import per_epoch

cfg = load_params()
out = {"capability": __import__("torch").backends.cpu.get_cpu_capability()}
with tempfile.TemporaryDirectory() as tmp:
    for name in sys.argv[3:]:
        threads = int(cfg.models[name].train.threads)
        out[name] = per_epoch(cfg, name, threads, Path(tmp) / f"{name}.pt")[0]
print(json.dumps(out))
"""


def _level(level: str, mkl: str = "-") -> dict:
    env = {k: v for k, v in os.environ.items() if k != "NANOSYSID_CPU_LEVEL"}
    r = subprocess.run([sys.executable, "-c", CHILD, level, mkl, *MODELS], cwd=ROOT, env=env,
                       capture_output=True, text=True)
    if r.returncode:
        raise SystemExit(f"pinned_level: the fits at level {level} failed:\n{r.stderr[-2000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def main() -> dict[str, float]:
    v3, v2, same = _level("v3"), _level("v2"), _level("v3", "COMPATIBLE")
    figures = {}
    for name in MODELS:
        print(f"{name:9s} {v3['capability']}: {v3[name]:.2f} s/epoch;  x86-64-v2 ({v2['capability']}): "
              f"{v2[name]:.2f} s/epoch ({v2[name] / v3[name]:.2f}x);  MKL COMPATIBLE: "
              f"{same[name]:.2f} s/epoch ({same[name] / v3[name]:.2f}x)")
        figures.update({f"{name}_s": v3[name], f"{name}_v2_s": v2[name],
                        f"{name}_v2_over_pinned": v2[name] / v3[name], f"{name}_mkl_compatible_s": same[name],
                        f"{name}_mkl_compatible_over_pinned": same[name] / v3[name]})
    figures["pinned"] = v3["capability"]
    return figures


if __name__ == "__main__":
    main()
