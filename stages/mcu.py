"""mcu: a model's generated C built for the Cortex-M4F, run on QEMU's STM32F405, checked against
PyTorch float32, its instructions per step, flash and RAM measured."""

import json
import logging
from pathlib import Path
from typing import Any

from omegaconf import DictConfig

from nanosysid import protocol
from nanosysid.dataio import atomic_dir, atomic_file, json_text
from nanosysid.errors import ConfigError, ExportError
from nanosysid.export import mcu
from nanosysid.report.paper import PAPER_COST
from stages.common import pick_flight, run_stage
from stages.export import export_dir, exportable_of

log = logging.getLogger("nanosysid.mcu")


def main(cfg: DictConfig, name: str) -> dict[str, Any]:
    """Build the exported C into firmware, run it on QEMU's STM32F405, compare it with PyTorch
    float32 and count its cost; firmware in ``<export.out_dir>/<name>/mcu/``, results in
    ``<paths.export>/<name>.json``. With ``export.mcu.enabled`` false, both say so and hold no
    figure (no toolchain needed)."""
    mc = cfg.export.mcu
    if not mc.enabled:
        return _skipped(cfg, name, SKIPPED)
    src = export_dir(cfg, name)
    summary = json.loads((src / "export.json").read_text()) if (src / "export.json").exists() else {}
    if summary.get("exportable") is False:
        return _skipped(cfg, name, f"not exported: {summary['reason']}")
    mcu.require_toolchain()
    ex = exportable_of(cfg, name)
    for f in ("nsi_model.h", "model.c"):
        if not (src / f).exists():
            raise ConfigError(f"{src / f}: not exported yet (run the export@{name} stage)")
    generated = (src / "model.c").read_text()
    if generated != ex.c.source:
        raise ExportError(f"{src / 'model.c'}: differs from the C generated from the model now; rerun export@{name}")

    bench = protocol.load(cfg.paths.split, horizon=int(cfg.eval.horizon))
    flight = pick_flight(bench.test, mc.flight, "export.mcu.flight")
    start, k = int(mc.start), int(mc.steps)
    if start + k > len(flight):
        raise ConfigError(f"export.mcu.start={start}, steps={k}: beyond the {len(flight)} samples of {flight.name}")
    y_in = ex.outputs_in(flight.y[start:start + k])
    u_in = ex.inputs_in(flight)[start:start + k]
    ref = ex.teacher_forced(y_in, u_in)

    out = Path(cfg.export.out_dir) / name / "mcu"
    with atomic_dir(out, inputs=[cfg.paths.split, src]) as tmp:
        mcu.write_sources(tmp, ex.c, y_in, u_in)
        size = mcu.build(tmp)
        run = mcu.run(tmp, ex.ny)
    # relative to each output's range over the test flight
    rel = mcu.range_relative_diff(run.outputs, ref, ex.outputs_in(flight.y))
    tol = float(mc.tolerance)
    t_est_ms = run.instructions_per_step / mcu.CLOCK_HZ * 1e3
    graph = src / "step.onnx"
    paper = PAPER_COST.get(name, {}).get("t_inf_ms")
    result = {
        "model": name, "flight": flight.name, "start": start, "steps": run.steps,
        "max_rel_diff": rel, "tolerance": tol,
        "instructions": run.instructions_per_step, "instructions_total_run": run.instructions_total,
        "t_est_ms": t_est_ms, "t_est_note": "instructions / 168 MHz: a lower bound, a Cortex-M4 instruction takes >= 1 cycle",
        "t_max_ms": t_est_ms * mcu.MAX_CYCLES_PER_INSTRUCTION,
        "t_max_note": f"{mcu.MAX_CYCLES_PER_INSTRUCTION} cycles an instruction: an upper bound (the longest FPU "
                      "instruction, 14 cycles, plus 5 flash wait states at 168 MHz)",
        "onnx_operators": mcu.graph_operators(graph) if graph.exists() else None,
        "flash_kb": (size["text"] + size["data"]) / 1024, "ram_kb": (size["data"] + size["bss"] + size["stack"]) / 1024,
        "size_bytes": size, "paper_t_inf_ms": paper,
        "t_est_over_paper": None if paper is None else t_est_ms / paper,
        "cflags": mcu.CFLAGS,
    }
    if not rel <= tol:
        raise ExportError(f"{out / 'firmware.elf'}: outputs differ from PyTorch float32 by {rel:.3g} "
                          f"(relative to each output's range, tolerance {tol:g})")
    with atomic_file(Path(cfg.paths.export) / f"{name}.json") as f:
        f.write_text(json_text(result))
    log.info("mcu %s: %.0f instructions per step (%.3f ms at 168 MHz), flash %.1f kB, RAM %.1f kB, rel. diff %.2g",
             name, run.instructions_per_step, t_est_ms, result["flash_kb"], result["ram_kb"], rel)
    return result


SKIPPED = "export.mcu.enabled is false: not built or run on the microcontroller"


def _skipped(cfg: DictConfig, name: str, why: str) -> dict[str, Any]:
    """The stage's outputs where the model is not run on the microcontroller (switched off, or
    nothing exported): a note in the firmware folder, and a result with the model's name and
    why it has no figures."""
    result = {"model": name, "skipped": why}
    with atomic_dir(Path(cfg.export.out_dir) / name / "mcu") as tmp:
        (tmp / "SKIPPED.txt").write_text(why + "\n")
    with atomic_file(Path(cfg.paths.export) / f"{name}.json") as f:
        f.write_text(json_text(result))
    log.info("mcu %s: %s", name, why)
    return result


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__, name_arg="model"))
