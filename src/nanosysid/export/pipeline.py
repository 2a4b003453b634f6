"""The export and mcu stages' work: one model to ONNX and C, then that C on the emulated STM32."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
from omegaconf import DictConfig, OmegaConf

from nanosysid import benchmark
from nanosysid.config import ConfigError
from nanosysid.dataio import atomic_dir, atomic_file
from nanosysid.export import ExportError, mcu
from nanosysid.export.steps import check_inputs, export_onnx, exportable, onnx_outputs
from nanosysid.models import build_from_config
from nanosysid.report import PAPER_COST

__all__ = ["export_model", "mcu_model", "export_dir", "mcu_dir"]

log = logging.getLogger(__name__)


def export_dir(cfg: DictConfig, name: str) -> Path:
    return Path(cfg.export.out_dir) / name / "export"


def mcu_dir(cfg: DictConfig, name: str) -> Path:
    return Path(cfg.export.out_dir) / name / "mcu"


def _exportable(cfg: DictConfig, name: str):
    if name not in cfg.models:
        raise ConfigError(f"models.{name}: no such model in the config (known: {', '.join(cfg.models)})")
    return exportable(build_from_config(OmegaConf.to_container(cfg.models[name], resolve=True)), name)


def export_model(cfg: DictConfig, name: str) -> dict[str, Any]:
    """ONNX of the step checked against PyTorch with onnxruntime, the generated C, and the
    step's cost, into ``<export.out_dir>/<name>/export/`` (replaced as a whole)."""
    ex = _exportable(cfg, name)
    ec = cfg.export
    bench = benchmark.load(cfg.paths.split, horizon=int(cfg.eval.horizon))
    inputs = check_inputs(ex, bench.test, int(ec.onnx_samples), int(cfg.seed))
    out = export_dir(cfg, name)
    with atomic_dir(out) as tmp:
        files = export_onnx(ex, tmp)
        import torch

        with torch.no_grad():
            if ex.kind == "lstm":
                ref = ex.step(*(torch.from_numpy(inputs[k]) for k in ("y", "u", "h", "c")))
                got = onnx_outputs(files[0], inputs)
                y0 = inputs["y"]
                diffs = [np.abs(g - r.numpy()).max() for g, r in zip(got, ref)]
                diffs += [np.abs(g - r.numpy()).max() for g, r in
                          zip(onnx_outputs(files[1], {"y": y0}), ex.init(torch.from_numpy(y0)))]
            else:
                ref = ex.step(torch.from_numpy(inputs["y"]), torch.from_numpy(inputs["u"]))
                diffs = [np.abs(onnx_outputs(files[0], inputs)[0] - ref.numpy()).max()]
        max_diff = float(max(diffs))
        tol = float(ec.onnx_tolerance)
        if not max_diff <= tol:
            raise ExportError(f"{files[0]}: onnxruntime differs from PyTorch by {max_diff:.3g} (tolerance {tol:g})")
        (tmp / "nsi_model.h").write_text(ex.c.header)
        (tmp / "model.c").write_text(ex.c.source)
        summary = {
            "model": name, "kind": ex.kind, "params": ex.params, "flops": ex.c.flops,
            "flops_note": "operations of the generated C step: 2 per multiply-add, 1 per other operation, "
                          "1 per tanh, sigmoid, square root or trigonometric function",
            "onnx": {"files": [f.name for f in files], "samples": int(ec.onnx_samples),
                     "max_abs_diff": max_diff, "tolerance": tol},
            "c": {"ny": ex.ny, "nstate": ex.c.nstate, **ex.c.notes},
        }
        (tmp / "export.json").write_text(json.dumps(summary, indent=1) + "\n")
    log.info("export %s: ONNX max |diff| %.2g over %d inputs, C step of %d operations",
             name, max_diff, int(ec.onnx_samples), ex.c.flops)
    return summary


def mcu_model(cfg: DictConfig, name: str) -> dict[str, Any]:
    """Build the exported C into firmware, run it on QEMU's STM32F405, compare it with PyTorch
    float32 and count its cost; firmware in ``<export.out_dir>/<name>/mcu/``, results in
    ``<paths.export>/<name>.json``."""
    mcu.require_toolchain()
    ex = _exportable(cfg, name)
    mc = cfg.export.mcu
    src = export_dir(cfg, name)
    for f in ("nsi_model.h", "model.c"):
        if not (src / f).exists():
            raise ConfigError(f"{src / f}: not exported yet (run the export@{name} stage)")
    generated = (src / "model.c").read_text()
    if generated != ex.c.source:
        raise ExportError(f"{src / 'model.c'}: differs from the C generated from the model now; rerun export@{name}")

    from nanosysid.reporting import pick_flight

    bench = benchmark.load(cfg.paths.split, horizon=int(cfg.eval.horizon))
    flight = pick_flight(bench.test, mc.flight, "export.mcu.flight")
    start, k = int(mc.start), int(mc.steps)
    if start + k > len(flight):
        raise ConfigError(f"export.mcu.start={start}, steps={k}: beyond the {len(flight)} samples of {flight.name}")
    y_in = ex.outputs_in(flight.y[start:start + k])
    u_in = ex.inputs_in(flight)[start:start + k]
    ref = ex.teacher_forced(y_in, u_in)

    out = mcu_dir(cfg, name)
    with atomic_dir(out) as tmp:
        mcu.write_sources(tmp, ex.c, y_in, u_in)
        size = mcu.build(tmp)
        run = mcu.run(tmp, ex.ny)
    # relative to each output channel's range over the steps, so near-zero values do not inflate it
    scale = np.maximum(np.abs(ref).max(axis=0), 1e-6)
    rel = float((np.abs(run.outputs - ref) / scale).max())
    tol = float(mc.tolerance)
    t_est_ms = run.instructions_per_step / mcu.CLOCK_HZ * 1e3
    paper = PAPER_COST.get(name, {}).get("t_inf_ms")
    result = {
        "model": name, "flight": flight.name, "start": start, "steps": run.steps,
        "max_rel_diff": rel, "tolerance": tol,
        "instructions": run.instructions_per_step, "instructions_total_run": run.instructions_total,
        "t_est_ms": t_est_ms, "t_est_note": "instructions / 168 MHz: a lower bound, a Cortex-M4 instruction takes >= 1 cycle",
        "flash_kb": (size["text"] + size["data"]) / 1024, "ram_kb": (size["data"] + size["bss"] + size["stack"]) / 1024,
        "size_bytes": size, "paper_t_inf_ms": paper,
        "t_est_over_paper": None if paper is None else t_est_ms / paper,
        "cflags": mcu.CFLAGS,
    }
    if not rel <= tol:
        raise ExportError(f"{out / 'firmware.elf'}: outputs differ from PyTorch float32 by {rel:.3g} "
                          f"(relative to each output's range, tolerance {tol:g})")
    with atomic_file(Path(cfg.paths.export) / f"{name}.json") as f:
        f.write_text(json.dumps(result, indent=1) + "\n")
    log.info("mcu %s: %.0f instructions per step (%.3f ms at 168 MHz), flash %.1f kB, RAM %.1f kB, rel. diff %.2g",
             name, run.instructions_per_step, t_est_ms, result["flash_kb"], result["ram_kb"], rel)
    return result
