"""export: a model's step to ONNX (checked with onnxruntime) and to C99, with its cost per step."""

import logging
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig

from nanosysid import protocol
from nanosysid.errors import ExportError, NotExportable
from nanosysid.export.steps import Exportable, check_inputs, export_onnx, onnx_outputs
from nanosysid.dataio import atomic_dir, json_text
from nanosysid.predictors import build_from_options, exportable
from stages.common import model_options, run_stage

log = logging.getLogger("nanosysid.export")


def export_dir(cfg: DictConfig, name: str) -> Path:
    return Path(cfg.export.out_dir) / name / "export"


def exportable_of(cfg: DictConfig, name: str) -> Exportable:
    """The exportable step of ``models.<name>``, through the model registry."""
    options = model_options(cfg, name)
    return exportable(options["kind"], build_from_options(options), name)


def main(cfg: DictConfig, name: str) -> dict[str, Any]:
    """ONNX of the step checked against PyTorch with onnxruntime, the generated C, and the
    step's cost, into ``<export.out_dir>/<name>/export/`` (replaced as a whole). A model whose
    step needs what the exported step is not given gets ``export.json`` saying why, and no step."""
    try:
        ex = exportable_of(cfg, name)
    except NotExportable as e:
        summary = {"model": name, "exportable": False, "reason": str(e)}
        with atomic_dir(export_dir(cfg, name)) as tmp:
            (tmp / "export.json").write_text(json_text(summary))
        log.warning("export %s: not exported: %s", name, e)
        return summary
    ec = cfg.export
    bench = protocol.load(cfg.paths.split, horizon=int(cfg.eval.horizon))
    inputs = check_inputs(ex, bench.test, int(ec.onnx_samples), int(cfg.seed))
    out = export_dir(cfg, name)
    with atomic_dir(out, inputs=[cfg.paths.split]) as tmp:
        files = export_onnx(ex, tmp)
        with torch.no_grad():
            if ex.recurrent:
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
        (tmp / "export.json").write_text(json_text(summary))
    log.info("export %s: ONNX max |diff| %.2g over %d inputs, C step of %d operations",
             name, max_diff, int(ec.onnx_samples), ex.c.flops)
    return summary


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__, name_arg="model"))
