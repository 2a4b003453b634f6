"""A benchmark model as an exportable step: its torch modules (for ONNX), its generated C,
and the teacher-forced reference its exports are checked against."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from nanosysid.discover.model import augmented_inputs, integrating
from nanosysid.effects import entry
from nanosysid.errors import ExportError, NotExportable
from nanosysid.export.csource import CModel, learned_source, physics_source
from nanosysid.models.learned import to_tilde
from nanosysid.models.physics import PhysicsStep

__all__ = ["Exportable", "physics_step", "augmented_step", "learned_step", "export_onnx", "onnx_outputs",
           "check_inputs"]


class _FeedForwardStep(nn.Module):
    def __init__(self, model) -> None:
        super().__init__()
        self.model = model

    def forward(self, yt: Tensor, u: Tensor) -> Tensor:
        return self.model.step(yt, u, None)[0]


class _RecurrentStep(nn.Module):
    def __init__(self, model) -> None:
        super().__init__()
        self.model = model

    def forward(self, yt: Tensor, u: Tensor, h: Tensor, c: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        y_next, (h, c) = self.model.step(yt, u, (h, c))
        return y_next, h, c


class _RecurrentInit(nn.Module):
    def __init__(self, model) -> None:
        super().__init__()
        self.model = model

    def forward(self, yt: Tensor) -> tuple[Tensor, Tensor]:
        return self.model.init_state(yt)


@dataclass
class Exportable:
    """One model's step in float32.

    ``kind`` says what it is (``physics``, ``augmented``, ``feedforward``, ``recurrent``). The
    physics steps work on the 13-dimensional outputs, the learned ones on the 12-dimensional
    representation (``ny``); a recurrent step carries a hidden and a cell state, which
    ``init`` computes from the first output.
    """

    name: str
    kind: str
    step: nn.Module
    init: nn.Module | None
    c: CModel
    params: int | None
    delay: float = 0.0  # s, the augmented model's rotor-speed delay (its inputs are read this much later)
    with_rates: bool = False  # the input holds the rotor speeds' rates too (the augmented model)

    @property
    def ny(self) -> int:
        return self.c.ny

    @property
    def nu(self) -> int:
        return 8 if self.with_rates else 4

    @property
    def recurrent(self) -> bool:
        return self.init is not None

    def inputs_in(self, flight) -> np.ndarray:
        """The step's input along a flight, ``(T, nu)`` float32: rotor speeds, and for the
        augmented model the speeds read ``delay`` later and their rates."""
        if not self.with_rates:
            return flight.u.astype(np.float32)

        u = torch.from_numpy(flight.u)[None]
        return augmented_inputs(u, self.delay, float(self.step.dt))[0].float().numpy()

    def outputs_in(self, y: np.ndarray) -> np.ndarray:
        """Flight outputs ``(N, 13)`` in the step's representation ``(N, ny)``, float32."""
        t = torch.from_numpy(np.ascontiguousarray(y, dtype=np.float64))
        if self.ny == 12:
            t = to_tilde(t)
        return t.float().numpy()

    @torch.no_grad()
    def teacher_forced(self, y_in: np.ndarray, u_in: np.ndarray) -> np.ndarray:
        """The step on ``y_in[k], u_in[k]`` for k = 0..K-1, state carried from ``y_in[0]``
        (what the firmware runs): ``(K, ny)`` float32."""
        y, u = torch.from_numpy(np.asarray(y_in, np.float32)), torch.from_numpy(np.asarray(u_in, np.float32))
        if not self.recurrent:
            return self.step(y, u).numpy()
        h, c = self.init(y[:1])
        out = []
        for k in range(len(y)):
            y_next, h, c = self.step(y[k:k + 1], u[k:k + 1], h, c)
            out.append(y_next[0])
        return torch.stack(out).numpy()


def physics_step(predict, name: str) -> Exportable:
    """The exportable step of a physics model (a :class:`~nanosysid.rollout.StepPredictor` of a
    :class:`~nanosysid.models.physics.PhysicsStep`)."""
    p = predict.step
    step = PhysicsStep(p.vehicle, dt=p.dt, substeps=p.substeps, angular_dynamics=p.angular_dynamics)
    c = physics_source(name, p.vehicle, dt=p.dt, substeps=p.substeps, angular_dynamics=p.angular_dynamics)
    return Exportable(name, "physics", step.float().eval(), None, c, None)


def augmented_step(predict, name: str) -> Exportable:
    """The exportable step of the discovered model (an :class:`~nanosysid.discover.model.AugmentedPredictor`)."""
    p = predict.step
    if p.history:
        slow = [e for e in p.effects if "history" in entry(e).needs]
        raise NotExportable(f"{name}: its effects {', '.join(slow)} read the rotor speeds' history (slow "
                            "actuation), which the exported step is not given")
    effects = list(p.coefficients().items())
    step = integrating(predict, p.integrated).step  # a copy: the export's float cast leaves the model as it is
    c = physics_source(name, p.vehicle, dt=p.dt, substeps=p.substeps, angular_dynamics=p.integrated, effects=effects)
    return Exportable(name, "augmented", step.float().eval(), None, c, None, delay=predict.delay, with_rates=True)


def learned_step(predict, name: str) -> Exportable:
    """The exportable step of a learned model (a :class:`~nanosysid.models.learned.LearnedPredictor`)."""
    import copy

    model = copy.deepcopy(predict.model).float().eval()
    params = sum(q.numel() for q in model.parameters() if q.requires_grad)
    c = learned_source(name, model)
    if model.network.recurrent:
        return Exportable(name, "recurrent", _RecurrentStep(model).eval(), _RecurrentInit(model).eval(), c, params)
    return Exportable(name, "feedforward", _FeedForwardStep(model).eval(), None, c, params)


def check_inputs(ex: Exportable, flights, n: int, seed: int) -> dict[str, np.ndarray]:
    """``n`` inputs of the step drawn (seeded) from the flights: outputs and rotor speeds of
    random samples; for a recurrent step also its state, after 0..49 steps from a random start."""
    rng = np.random.default_rng(seed)
    y = np.concatenate([f.y for f in flights])
    u = np.concatenate([ex.inputs_in(f) for f in flights])
    if not ex.recurrent:
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
    """``step.onnx`` (and ``init.onnx`` for a recurrent step) in ``out``; batch size is dynamic."""
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
    if ex.recurrent:
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
