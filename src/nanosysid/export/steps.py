"""A benchmark model as an exportable step: its torch modules (for ONNX), its generated C,
and the teacher-forced reference its exports are checked against."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from nanosysid.export import ExportError
from nanosysid.export.csource import CModel, learned_source, physics_source

__all__ = ["Exportable", "exportable", "ExportError", "export_onnx", "onnx_outputs", "check_inputs"]


class _FeedForwardStep(nn.Module):
    def __init__(self, model) -> None:
        super().__init__()
        self.model = model

    def forward(self, yt: Tensor, u: Tensor) -> Tensor:
        return self.model.step(yt, u, None)[0]


class _LstmStep(nn.Module):
    def __init__(self, model) -> None:
        super().__init__()
        self.model = model

    def forward(self, yt: Tensor, u: Tensor, h: Tensor, c: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        y_next, (h, c) = self.model.step(yt, u, (h, c))
        return y_next, h, c


class _LstmInit(nn.Module):
    def __init__(self, model) -> None:
        super().__init__()
        self.model = model

    def forward(self, yt: Tensor) -> tuple[Tensor, Tensor]:
        return self.model.init_state(yt)


@dataclass
class Exportable:
    """One model's step in float32.

    ``kind`` is ``physics`` (outputs of 13, no state), ``feedforward`` (the 12-dimensional
    outputs of the learned models, no state) or ``lstm`` (12, with hidden and cell state).
    """

    name: str
    kind: str
    step: nn.Module
    init: nn.Module | None
    c: CModel
    params: int | None
    delay: float = 0.0  # s, the augmented model's rotor-speed delay (its inputs are read this much later)

    @property
    def ny(self) -> int:
        return self.c.ny

    @property
    def nu(self) -> int:
        return 8 if self.kind == "augmented" else 4

    def inputs_in(self, flight) -> np.ndarray:
        """The step's input along a flight, ``(T, nu)`` float32: rotor speeds, and for the
        augmented model the speeds read ``delay`` later and their rates."""
        if self.kind != "augmented":
            return flight.u.astype(np.float32)
        from nanosysid.discover.model import augmented_inputs

        u = torch.from_numpy(flight.u)[None]
        return augmented_inputs(u, self.delay, float(self.step.dt))[0].float().numpy()

    def outputs_in(self, y: np.ndarray) -> np.ndarray:
        """Flight outputs ``(N, 13)`` in the step's representation ``(N, ny)``, float32."""
        from nanosysid.models.learned import to_tilde

        t = torch.from_numpy(np.ascontiguousarray(y, dtype=np.float64))
        if self.kind not in ("physics", "augmented"):
            t = to_tilde(t)
        return t.float().numpy()

    @torch.no_grad()
    def teacher_forced(self, y_in: np.ndarray, u_in: np.ndarray) -> np.ndarray:
        """The step on ``y_in[k], u_in[k]`` for k = 0..K-1, state carried from ``y_in[0]``
        (what the firmware runs): ``(K, ny)`` float32."""
        y, u = torch.from_numpy(np.asarray(y_in, np.float32)), torch.from_numpy(np.asarray(u_in, np.float32))
        if self.kind != "lstm":
            return self.step(y, u).numpy()
        h, c = self.init(y[:1])
        out = []
        for k in range(len(y)):
            y_next, h, c = self.step(y[k:k + 1], u[k:k + 1], h, c)
            out.append(y_next[0])
        return torch.stack(out).numpy()


def exportable(predict: Any, name: str) -> Exportable:
    """The exportable step of a benchmark predictor (physics, learned or discovered)."""
    from nanosysid.discover import CANDIDATES
    from nanosysid.discover.model import AugmentedPredictor, AugmentedStep
    from nanosysid.models.learned import LearnedPredictor
    from nanosysid.models.physics import PhysicsStep
    from nanosysid.rollout import StepPredictor

    if isinstance(predict, StepPredictor) and isinstance(predict.step, PhysicsStep):
        p = predict.step
        step = PhysicsStep(p.vehicle, dt=p.dt, substeps=p.substeps, angular_dynamics=p.angular_dynamics)
        c = physics_source(name, p.vehicle, dt=p.dt, substeps=p.substeps, angular_dynamics=p.angular_dynamics)
        return Exportable(name, "physics", step.float().eval(), None, c, None)
    if isinstance(predict, AugmentedPredictor):
        p = predict.step
        theta, effects, k = p.theta.tolist(), [], 0
        for n in p.effects:
            effects.append((n, theta[k:k + len(CANDIDATES[n].params)]))
            k += len(CANDIDATES[n].params)
        step = AugmentedStep(p.vehicle, p.effects, theta, dt=p.dt, substeps=p.substeps)
        c = physics_source(name, p.vehicle, dt=p.dt, substeps=p.substeps, angular_dynamics=True, effects=effects)
        return Exportable(name, "augmented", step.float().eval(), None, c, None, delay=predict.delay)
    if isinstance(predict, LearnedPredictor):
        import copy

        model = copy.deepcopy(predict.model).float().eval()
        params = sum(q.numel() for q in model.parameters() if q.requires_grad)
        c = learned_source(name, model)
        if model.arch == "lstm":
            return Exportable(name, "lstm", _LstmStep(model).eval(), _LstmInit(model).eval(), c, params)
        return Exportable(name, "feedforward", _FeedForwardStep(model).eval(), None, c, params)
    raise ExportError(f"model {name!r} ({type(predict).__name__}) has no exportable step: "
                      "physics models and learned checkpoints export")


def check_inputs(ex: Exportable, flights, n: int, seed: int) -> dict[str, np.ndarray]:
    """``n`` inputs of the step drawn (seeded) from the flights: outputs and rotor speeds of
    random samples; for the LSTM also its state, after 0..49 steps from a random start."""
    rng = np.random.default_rng(seed)
    y = np.concatenate([f.y for f in flights])
    u = np.concatenate([ex.inputs_in(f) for f in flights])
    if ex.kind != "lstm":
        idx = rng.integers(0, len(y), n)
        return {"y": ex.outputs_in(y[idx]), "u": u[idx]}
    H = 50
    lengths = np.array([len(f) for f in flights])
    offsets = np.cumsum(lengths) - lengths
    flight = rng.integers(0, len(flights), n)
    start = offsets[flight] + rng.integers(0, lengths[flight] - H)
    k = rng.integers(0, H, n)
    yt = torch.from_numpy(ex.outputs_in(y))
    ut = torch.from_numpy(u)
    with torch.no_grad():
        h, c = ex.init(yt[start])
        hs, cs = [h], [c]
        for j in range(H - 1):
            _, h, c = ex.step(yt[start + j], ut[start + j], h, c)
            hs.append(h)
            cs.append(c)
    rows = np.arange(n)
    h = torch.stack(hs)[k, rows].numpy()  # (n, hidden): the state after k steps
    c = torch.stack(cs)[k, rows].numpy()
    return {"y": yt[start + k].numpy(), "u": u[start + k], "h": h, "c": c}


def export_onnx(ex: Exportable, out: Path) -> list[Path]:
    """``step.onnx`` (and ``init.onnx`` for the LSTM) in ``out``; batch size is dynamic."""
    import warnings

    def one(module: nn.Module, args: tuple, names_in: list[str], names_out: list[str], path: Path) -> None:
        with warnings.catch_warnings():
            # the TorchScript exporter is deprecated in favour of the dynamo one, which needs onnxscript
            warnings.simplefilter("ignore", DeprecationWarning)
            # the physics step's constants are constants: that is what the trace should record
            warnings.simplefilter("ignore", torch.jit.TracerWarning)
            torch.onnx.export(module, args, str(path), dynamo=False, input_names=names_in, output_names=names_out,
                              dynamic_axes={n: {0: "batch"} for n in names_in + names_out}, opset_version=17)

    ny, z = ex.ny, torch.zeros
    files = [out / "step.onnx"]
    if ex.kind == "lstm":
        nh = ex.c.nstate // 2
        one(ex.step, (z(1, ny), z(1, 4), z(1, nh), z(1, nh)), ["y", "u", "h", "c"], ["y_next", "h_next", "c_next"],
            files[0])
        files.append(out / "init.onnx")
        one(ex.init, (z(1, ny),), ["y"], ["h", "c"], files[1])
    else:
        one(ex.step, (z(1, ny), z(1, ex.nu)), ["y", "u"], ["y_next"], files[0])
    return files


def onnx_outputs(path: Path, inputs: dict[str, np.ndarray]) -> list[np.ndarray]:
    """Run an ONNX file with onnxruntime on the CPU."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    sess = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    names = [i.name for i in sess.get_inputs()]
    return sess.run(None, {n: np.ascontiguousarray(inputs[n], dtype=np.float32) for n in names})
