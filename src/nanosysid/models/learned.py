"""Learned models: the residual MLP, physics + residual, and the LSTM of the paper.

All three work in the paper's 12-dimensional representation ``ỹ = [p, v, r, w]`` (the
rotation vector ``r = log q`` in place of the quaternion) and predict increments:
``ỹ_{k+1} = ỹ_k + Δ`` (residual, LSTM) or ``ỹ_{k+1} = f_phys(ỹ_k, u_k) + Δ`` (phys_res).
Inputs are normalised with statistics of the training flights, and increments are predicted
in units of their training standard deviation; the statistics are buffers of the model, so a
checkpoint is self-contained.

The step map, the rollout and the initial-state handling are separate: ``init_state`` (the
LSTM's hidden state from ``ỹ_0``), ``step`` (one sample) and ``rollout`` (H samples).
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from nanosysid import so3
from nanosysid.models.physics import PhysicsStep
from nanosysid.rollout import as_tensor
from nanosysid.vehicle import Vehicle

__all__ = ["to_tilde", "from_tilde", "MLP", "SequenceModel", "build_model", "save_checkpoint", "load_model",
           "LearnedPredictor", "ARCHS"]

ARCHS = ("residual", "phys_res", "lstm")


def to_tilde(y: Tensor) -> Tensor:
    """``(..., 13)`` outputs to the 12-dimensional representation (quaternion -> rotation vector)."""
    return torch.cat((y[..., :6], so3.quat_log(y[..., 6:10]), y[..., 10:13]), dim=-1)


def from_tilde(yt: Tensor) -> Tensor:
    """``(..., 12)`` back to ``(..., 13)`` outputs."""
    return torch.cat((yt[..., :6], so3.quat_exp(yt[..., 6:9]), yt[..., 9:12]), dim=-1)


class MLP(nn.Sequential):
    """Fully connected network with tanh activations between layers."""

    def __init__(self, n_in: int, hidden: list[int], n_out: int) -> None:
        layers: list[nn.Module] = []
        for h in hidden:
            layers += [nn.Linear(n_in, h), nn.Tanh()]
            n_in = h
        layers.append(nn.Linear(n_in, n_out))
        super().__init__(*layers)


class SequenceModel(nn.Module):
    """One learned model: network, normalisation and (for phys_res) the physics step.

    Args:
        arch: ``residual``, ``phys_res`` or ``lstm``.
        hidden: Hidden layer sizes of the feed-forward network (residual, phys_res).
        lstm_hidden: Hidden size of the LSTM; ``init_hidden``: the hidden layer of the MLP
            that maps ``ỹ_0`` to the LSTM's initial hidden and cell states.
        physics: The physics step of phys_res (its vehicle holds the identified k_F, k_M).
    """

    def __init__(self, arch: str, *, hidden: list[int] = (120, 120), lstm_hidden: int = 64, init_hidden: int = 32,
                 physics: PhysicsStep | None = None) -> None:
        super().__init__()
        if arch not in ARCHS:
            raise ValueError(f"unknown architecture {arch!r}; known: {', '.join(ARCHS)}")
        self.arch = arch
        self.physics = physics
        if arch == "phys_res" and physics is None:
            raise ValueError("phys_res needs a physics step")
        if arch == "lstm":
            self.init = MLP(12, [init_hidden], 2 * lstm_hidden)
            self.cell = nn.LSTMCell(16, lstm_hidden)
            self.readout = nn.Linear(lstm_hidden, 12)
        else:
            self.net = MLP(16, list(hidden), 12)
            if arch == "phys_res":
                # the residual starts at zero, so the untrained model is the physics model
                nn.init.zeros_(self.net[-1].weight)
                nn.init.zeros_(self.net[-1].bias)
        for name, n in (("y_mean", 12), ("y_std", 12), ("u_mean", 4), ("u_std", 4), ("d_std", 12)):
            self.register_buffer(name, torch.zeros(n) if "mean" in name else torch.ones(n))

    def set_statistics(self, y_tilde: Tensor, u: Tensor, d: Tensor) -> None:
        """Normalisation from training data: outputs ``(N, 12)``, inputs ``(N, 4)``, increments ``(N, 12)``."""
        self.y_mean.copy_(y_tilde.mean(0))
        self.y_std.copy_(y_tilde.std(0).clamp_min(1e-6))
        self.u_mean.copy_(u.mean(0))
        self.u_std.copy_(u.std(0).clamp_min(1e-6))
        self.d_std.copy_(d.std(0).clamp_min(1e-9))

    def _features(self, yt: Tensor, u: Tensor) -> Tensor:
        return torch.cat(((yt - self.y_mean) / self.y_std, (u - self.u_mean) / self.u_std), dim=-1)  # (B, 16)

    def init_state(self, yt0: Tensor) -> Any:
        """Recurrent state from the initial output (LSTM: hidden and cell); None otherwise."""
        if self.arch != "lstm":
            return None
        h, c = self.init((yt0 - self.y_mean) / self.y_std).chunk(2, dim=-1)
        return (torch.tanh(h), c)

    def step(self, yt: Tensor, u: Tensor, state: Any = None) -> tuple[Tensor, Any]:
        """One sample ahead: ``ỹ_k (B, 12)``, ``u_k (B, 4)`` -> ``ỹ_{k+1}`` and the new state."""
        x = self._features(yt, u)
        if self.arch == "lstm":
            h, c = self.cell(x, state)
            return yt + self.d_std * self.readout(h), (h, c)
        base = yt
        if self.arch == "phys_res":
            base = to_tilde(self.physics(from_tilde(yt), u))
        return base + self.d_std * self.net(x), None

    def rollout(self, yt0: Tensor, u: Tensor) -> Tensor:
        """``ỹ_0 (B, 12)``, ``u (B, H, 4)`` -> predictions ``(B, H, 12)`` for h = 1..H."""
        state = self.init_state(yt0)
        yt, out = yt0, []
        for k in range(u.shape[1]):
            yt, state = self.step(yt, u[:, k], state)
            out.append(yt)
        return torch.stack(out, dim=1)


def build_model(hparams: dict[str, Any]) -> SequenceModel:
    """A model from its hyper-parameters (the ``arch`` block of a config or a checkpoint)."""
    physics = None
    if hparams["arch"] == "phys_res":
        v = hparams["vehicle"]
        vehicle = Vehicle.from_mapping(v)
        physics = PhysicsStep(vehicle, dt=hparams.get("dt", 0.01), substeps=hparams.get("substeps", 1),
                              angular_dynamics=False)
    return SequenceModel(
        hparams["arch"],
        hidden=list(hparams.get("hidden", [120, 120])),
        lstm_hidden=int(hparams.get("lstm_hidden", 64)),
        init_hidden=int(hparams.get("init_hidden", 32)),
        physics=physics,
    )


def save_checkpoint(model: SequenceModel, hparams: dict[str, Any], path: Path, extra: dict[str, Any] | None = None) -> None:
    """Weights, normalisation and hyper-parameters in one file, loadable with ``weights_only=True``."""
    from nanosysid.dataio import atomic_file

    payload = {"format": "nanosysid-model-1", "hparams": hparams, "state_dict": model.state_dict(),
               "extra": extra or {}}
    # torch names the archive's records after the file it writes to; through a buffer the
    # name is fixed, so the same weights give the same bytes whatever the (temporary) path
    buf = io.BytesIO()
    torch.save(payload, buf)
    with atomic_file(path) as tmp:
        tmp.write_bytes(buf.getvalue())


def load_model(path: str | Path) -> tuple[SequenceModel, dict[str, Any]]:
    """The one loader of learned models (evaluation, export and visualisation use it)."""
    ckpt = torch.load(path, map_location="cpu", weights_only=True)
    if ckpt.get("format") != "nanosysid-model-1":
        raise ValueError(f"{path}: not a nanosysid model checkpoint")
    model = build_model(ckpt["hparams"])
    model.load_state_dict(ckpt["state_dict"])
    model.eval()
    return model, ckpt


class LearnedPredictor:
    """A learned model as a benchmark predictor (13-dimensional outputs, numpy out)."""

    def __init__(self, model: SequenceModel, *, dtype: torch.dtype = torch.float64, name: str = "") -> None:
        self.model = model.to(dtype)
        self.dtype = dtype
        self.name = name

    @torch.no_grad()
    def __call__(self, y0, u) -> np.ndarray:
        yt0 = to_tilde(as_tensor(y0, self.dtype))
        return from_tilde(self.model.rollout(yt0, as_tensor(u, self.dtype))).numpy()
