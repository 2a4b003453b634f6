"""Learned models: the residual MLP, physics + residual, and the LSTM of the paper.

All three work in the paper's 12-dimensional representation ``ỹ = [p, v, r, w]`` (the
rotation vector ``r = log q`` in place of the quaternion) and predict increments:
``ỹ_{k+1} = ỹ_k + Δ`` (residual, LSTM) or ``ỹ_{k+1} = f_phys(ỹ_k, u_k) + Δ`` (phys_res).
Inputs are normalised with statistics of the training flights, and increments are predicted
in units of their training standard deviation; the statistics are buffers of the model, so a
checkpoint is self-contained.

The network is a component (:mod:`nanosysid.models.components`) injected into the one
:class:`SequenceModel`; the step map, the rollout and the initial-state handling are separate:
``init_state`` (a recurrent network's state from ``ỹ_0``), ``step`` (one sample) and
``rollout`` (H samples).
"""

from __future__ import annotations

import hashlib
import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from nanosysid import so3
from nanosysid.dataio import atomic_file
from nanosysid.errors import ConfigError, DataError
from nanosysid.models.components import network_class
from nanosysid.models.physics import PhysicsStep
from nanosysid.numerics import compiled
from nanosysid.rollout import as_tensor
from nanosysid.vehicle import Vehicle

__all__ = ["to_tilde", "from_tilde", "SequenceModel", "build_model", "build_network", "save_checkpoint", "load_checkpoint", "LearnedPredictor",
           "FORMAT"]

FORMAT = "nanosysid-model-3"


def to_tilde(y: Tensor) -> Tensor:
    """``(..., 13)`` outputs to the 12-dimensional representation (quaternion -> rotation vector)."""
    return torch.cat((y[..., :6], so3.quat_log(y[..., 6:10]), y[..., 10:13]), dim=-1)


def from_tilde(yt: Tensor) -> Tensor:
    """``(..., 12)`` back to ``(..., 13)`` outputs."""
    return torch.cat((yt[..., :6], so3.quat_exp(yt[..., 6:9]), yt[..., 9:12]), dim=-1)


class SequenceModel(nn.Module):
    """One learned model: an injected network, the normalisation, and optionally a physics base.

    ``ỹ_{k+1} = base + d_std * network(features)``, where the base is ``ỹ_k`` or, with a
    ``physics`` step, the physics model's prediction from ``ỹ_k`` (physics + residual).

    Args:
        network: A network of :mod:`nanosysid.models.components`.
        physics: The physics step of the base (its vehicle holds the identified k_F, k_M).
    """

    def __init__(self, network: nn.Module, physics: PhysicsStep | None = None) -> None:
        super().__init__()
        self.network = network
        self.physics = physics
        self._compiled_base = None  # compile_base()
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
        """The network's recurrent state from the initial output (None for feed-forward ones)."""
        return self.network.init_state((yt0 - self.y_mean) / self.y_std)

    def base(self, yt: Tensor, u: Tensor) -> Tensor:
        """What the network's increment is added to: ``ỹ_k (B, 12)`` itself, or with a physics
        base the physics model's prediction from it and ``u_k (B, 4)``."""
        return yt if self.physics is None else to_tilde(self.physics(from_tilde(yt), u))

    def compile_base(self, setting: str = "train.compile") -> None:
        """Run the physics base compiled (:func:`nanosysid.numerics.compiled`), one graph for
        every batch size: its few hundred small operations a step, forward and backward, bound a
        physics + residual model's training by their overhead. A model without a physics base
        is left as it is: its step is matrix products, no faster compiled."""
        if self.physics is not None:
            self._compiled_base = compiled(self.base, setting=setting, dynamic=True)

    def step(self, yt: Tensor, u: Tensor, state: Any = None) -> tuple[Tensor, Any]:
        """One sample ahead: ``ỹ_k (B, 12)``, ``u_k (B, 4)`` -> ``ỹ_{k+1}`` and the new state."""
        d, state = self.network(self._features(yt, u), state)
        return (self._compiled_base or self.base)(yt, u) + self.d_std * d, state

    def rollout(self, yt0: Tensor, u: Tensor) -> Tensor:
        """``ỹ_0 (B, 12)``, ``u (B, H, 4)`` -> predictions ``(B, H, 12)`` for h = 1..H."""
        state = self.init_state(yt0)
        yt, out = yt0, []
        for k in range(u.shape[1]):
            yt, state = self.step(yt, u[:, k], state)
            out.append(yt)
        return torch.stack(out, dim=1)


def _physics_spec(physics: PhysicsStep | None) -> dict[str, Any] | None:
    if physics is None:
        return None
    vehicle = {k: (list(v) if isinstance(v, tuple) else v) for k, v in physics.vehicle.dynamics_kwargs().items()}
    return {"vehicle": vehicle, "dt": physics.dt, "substeps": physics.substeps,
            "angular_dynamics": physics.angular_dynamics}


def content_hash(network: Any, physics: Any, state_dict: dict[str, Tensor]) -> str:
    """SHA-256 of what a checkpoint computes with: the network and physics specs and every tensor
    (name, dtype, shape and bytes, in order). Written into the checkpoint and compared on load,
    so weights changed after training (a bit flip whose zip CRC was recomputed, an edit by
    another tool) are caught, not evaluated."""
    h = hashlib.sha256(json.dumps([network, physics], sort_keys=True, default=str).encode())
    for name, t in state_dict.items():
        t = t.detach().cpu().contiguous()
        h.update(f"{name}|{t.dtype}|{tuple(t.shape)}|".encode())
        h.update(t.numpy().tobytes() if t.dtype != torch.bfloat16 else t.view(torch.int16).numpy().tobytes())
    return h.hexdigest()


def save_checkpoint(model: SequenceModel, network: dict[str, Any], path: Path,
                    extra: dict[str, Any] | None = None) -> None:
    """Weights, normalisation, the network (its :mod:`~nanosysid.models.components` key and
    constructor arguments) and the physics base in one file, loadable with
    ``weights_only=True``.

    Args:
        network: ``{"name": key, "options": {...}}``, what :func:`load_checkpoint` rebuilds.
    """
    physics, state = _physics_spec(model.physics), model.state_dict()
    payload = {"format": FORMAT, "network": network, "physics": physics, "state_dict": state,
               "sha256": content_hash(network, physics, state), "extra": extra or {}}
    # torch names the archive's records after the file it writes to; through a buffer the
    # name is fixed, so the same weights give the same bytes whatever the (temporary) path
    buf = io.BytesIO()
    torch.save(payload, buf)
    with atomic_file(path) as tmp:
        tmp.write_bytes(buf.getvalue())


def build_network(name: str, options: dict[str, Any]) -> nn.Module:
    """A network of :mod:`nanosysid.models.components` by key, with its constructor's arguments."""
    try:
        cls = network_class(name)
    except KeyError as e:
        raise ConfigError(e.args[0]) from None
    try:
        net = cls(**options)
    except (TypeError, ValueError, RuntimeError) as e:
        raise ConfigError(f"network {name!r}: {e}") from None
    # a layer of width 0 builds (as empty weights) but passes nothing through
    empty = [k for k, p in net.named_parameters() if p.numel() == 0]
    if empty:
        raise ConfigError(f"network {name!r}: options {options} give {empty[0]} no weights; every layer needs a "
                          "width of at least 1")
    return net


def build_model(network: dict[str, Any], physics: PhysicsStep | None = None) -> SequenceModel:
    """A model from its network spec ``{"name", "options"}`` and optional physics base."""
    return SequenceModel(build_network(network["name"], dict(network.get("options", {}))), physics)


def load_checkpoint(path: str | Path) -> tuple[SequenceModel, dict[str, Any]]:
    """The one loader of learned models (evaluation, export and visualisation use it).

    Raises:
        DataError: a missing, unreadable, foreign or inconsistent checkpoint, named with the
            problem; a payload that would need code to unpickle is refused, never run.
    """
    import pickle
    import zipfile

    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: no such checkpoint (train the model first: `dvc repro train@<model>`)")
    try:
        # torch reads a zip entry without its CRC: a flipped bit would load as other weights
        with zipfile.ZipFile(path) as z:
            bad = z.testzip()
        if bad is not None:
            raise DataError(f"{path}: the checkpoint is damaged (entry {bad!r} fails its CRC check); "
                            "train the model again or restore the file")
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        raise DataError(f"{path}: the checkpoint holds Python objects beyond tensors and plain data; it is "
                        "refused, since loading it would run its code. Save models with "
                        "nanosysid.models.learned.save_checkpoint") from None
    except (RuntimeError, EOFError, OSError, zipfile.BadZipFile, ValueError) as e:
        with open(path, "rb") as fh:
            legacy = isinstance(e, zipfile.BadZipFile) and fh.read(2) == b"\x80\x02"  # a pickle, protocol 2
        if legacy:
            raise DataError(f"{path}: a checkpoint in torch's older format (torch.save(..., "
                            "_use_new_zipfile_serialization=False)), not the zip format whose entries this loader "
                            "checks; save it again with nanosysid.models.learned.save_checkpoint") from None
        raise DataError(f"{path}: not a readable checkpoint, the file is damaged or truncated "
                        f"({type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''})") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        found = f"format {ckpt.get('format')!r}" if isinstance(ckpt, dict) else f"a bare {type(ckpt).__name__}"
        raise DataError(f"{path}: not a nanosysid model checkpoint (format {FORMAT}); it holds {found}")
    for key, kind in (("network", dict), ("physics", (dict, type(None))), ("state_dict", dict), ("sha256", str)):
        if not isinstance(ckpt.get(key), kind):
            raise DataError(f"{path}: field {key!r} is missing or malformed")
    found = content_hash(ckpt["network"], ckpt["physics"], ckpt["state_dict"])
    if found != ckpt["sha256"]:
        raise DataError(f"{path}: the weights or specs differ from those the checkpoint was written with (SHA-256 "
                        f"{found[:12]}…, recorded {ckpt['sha256'][:12]}…); train the model again or restore the file")
    net = ckpt["network"]
    try:
        physics = None
        if ckpt["physics"] is not None:
            p = ckpt["physics"]
            physics = PhysicsStep(Vehicle.from_mapping(p["vehicle"]), dt=p["dt"], substeps=p["substeps"],
                                  angular_dynamics=p["angular_dynamics"])
        model = build_model(net, physics)
    except (ConfigError, KeyError, TypeError, ValueError) as e:
        raise DataError(f"{path}: the network or physics it describes cannot be built ({e})") from None
    try:
        model.load_state_dict(ckpt["state_dict"])
    except RuntimeError as e:
        first = str(e).splitlines()
        raise DataError(f"{path}: the weights do not fit the network it names ({net.get('name')}): "
                        f"{' '.join(line.strip() for line in first[:3])}") from None
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
