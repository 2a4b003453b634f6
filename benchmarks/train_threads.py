"""Training of the three learned models on the pipeline's training flights with their own settings
(`models.<name>.train`), on one torch thread (the product's `train.threads`) against two (the
pinned count of the rest of the pipeline), in the same run: seconds and CPU seconds per epoch once
compiled (:func:`per_epoch`), at the x86-64-v2 level (`benchmarks/pinned_level.py` compares it
with the train stage's AVX2 one)."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from omegaconf import OmegaConf

from nanosysid import protocol
from nanosysid.config import load_params
from nanosysid.models.training import network_spec, optimiser_parts, physics_base, train_model

EPOCHS = 3
MODELS = ("residual", "phys_res", "lstm")


def _fit(cfg, name: str, threads: int, out: Path, epochs: int) -> tuple[float, float]:
    """Train ``name`` with its own settings of ``cfg`` for ``epochs`` on ``threads`` torch threads
    into ``out``: the wall and CPU seconds the fit took."""
    m = OmegaConf.to_container(cfg.models[name], resolve=True)
    t = m["train"]
    optimizer, scheduler = optimiser_parts(t["optimizer"], t["scheduler"])
    bench = protocol.load(cfg.paths.split, horizon=int(t["horizon"]))
    wall, cpu = time.perf_counter(), time.process_time()
    train_model(network_spec(m), bench.train, out, physics=physics_base(m), optimizer=optimizer, scheduler=scheduler,
                horizon=int(t["horizon"]), stride=int(t["stride"]), batch_size=int(t["batch_size"]), epochs=epochs,
                patience=epochs, seed=int(t["seed"]), val_runs=t["val_runs"], accelerator="cpu", devices=1,
                compile=bool(t["compile"]), threads=threads, progress=False)
    return time.perf_counter() - wall, time.process_time() - cpu


def per_epoch(cfg, name: str, threads: int, out: Path) -> tuple[float, float]:
    """The wall and CPU seconds of one more epoch of ``name`` on ``threads`` threads, once
    compiled: after a first fit of one epoch (phys_res's physics base is compiled for each thread
    count), a fit of :data:`EPOCHS` less one of one, over the epochs between (a fit's own start
    and end cancel)."""
    _, (w1, c1), (wn, cn) = (_fit(cfg, name, threads, out, epochs) for epochs in (1, 1, EPOCHS))
    return (wn - w1) / (EPOCHS - 1), (cn - c1) / (EPOCHS - 1)


def main() -> dict[str, float]:
    cfg = load_params()
    figures = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in MODELS:
            ours = int(cfg.models[name].train.threads)
            (w1, c1), (w2, c2) = (per_epoch(cfg, name, n, Path(tmp) / f"{name}{n}.pt") for n in (ours, 2))
            print(f"{name:9s} {ours} thread: {w1:.2f} s/epoch, {c1:.2f} CPU s/epoch;  2 threads: {w2:.2f} s/epoch "
                  f"({w2 / w1:.2f}x), {c2:.2f} CPU s/epoch ({c2 / c1:.2f}x)")
            figures.update({f"{name}_s": w1, f"{name}_cpu_s": c1, f"{name}_two_threads_s": w2,
                            f"{name}_two_threads_cpu_s": c2, f"{name}_cpu_ratio": c2 / c1})
    return figures


if __name__ == "__main__":
    main()
