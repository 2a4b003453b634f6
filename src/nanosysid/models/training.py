"""Training of the learned models: one LightningModule for all; the network, the optimiser and
the scheduler are injected (the train stage builds them from the model's config).

Windows of H samples are cut from the training flights (every ``stride``-th start); the model
is rolled out over each window from its first sample and compared with every step
(multi-step loss, in units of the output standard deviations). Early stopping watches the
same loss on the validation flights (by default run 4 of each training trajectory).
"""

from __future__ import annotations

import contextlib
import logging
import sys
import warnings
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, Sequence

import numpy as np
import pytorch_lightning as pl
from hydra.utils import instantiate
import torch
from torch import Tensor
from torch.utils.data import BatchSampler, DataLoader, RandomSampler, SequentialSampler, TensorDataset

from nanosysid.protocol import windows
from nanosysid.dataio import Flight
from nanosysid.errors import ConfigError
from nanosysid.identify import identified_vehicle
from nanosysid.models.learned import SequenceModel, build_model, save_checkpoint, to_tilde
from nanosysid.models.physics import PhysicsStep
from nanosysid.numerics import quiet_tracing, threads as torch_threads
from nanosysid.vehicle import Vehicle

__all__ = ["SysIdModule", "window_tensors", "train_model", "network_spec", "physics_base", "optimiser_parts"]

log = logging.getLogger(__name__)


class SysIdModule(pl.LightningModule):
    """Multi-step rollout training of any :class:`SequenceModel`.

    Args:
        model: The model, its network injected.
        optimizer: ``optimizer(params) -> torch.optim.Optimizer`` (a partial of the config's
            ``optimizer``); Adam at 1e-3 if None.
        scheduler: ``scheduler(optimizer)``, stepped on the validation loss; none if None.
        horizon_decay: Step h of a window weighs ``exp(-horizon_decay (h - 1))`` in the loss, the
            weights scaled to a mean of 1 (the benchmark authors' loss takes 0.1); 0: every step
            alike.
    """

    def __init__(self, model: SequenceModel, *, optimizer: Callable | None = None,
                 scheduler: Callable | None = None, horizon_decay: float = 0.0) -> None:
        super().__init__()
        self.model = model
        self.horizon_decay = float(horizon_decay)
        self.optimizer = optimizer or (lambda params: torch.optim.Adam(params, lr=1e-3))
        self.scheduler = scheduler

    def loss(self, batch: tuple[Tensor, Tensor, Tensor]) -> Tensor:
        yt0, u, target = batch  # (B, 12), (B, H, 4), (B, H, 12)
        pred = self.model.rollout(yt0, u)
        err = ((pred - target) / self.model.y_std) ** 2
        if self.horizon_decay:
            h = torch.arange(err.shape[1], dtype=err.dtype, device=err.device)
            w = torch.exp(-self.horizon_decay * h)
            err = err * (w / w.mean())[:, None]
        return err.mean()

    def training_step(self, batch, batch_idx):
        loss = self.loss(batch)
        self.log("train/loss", loss, on_step=False, on_epoch=True, prog_bar=True)
        return loss

    def validation_step(self, batch, batch_idx):
        self.log("val/loss", self.loss(batch), on_step=False, on_epoch=True, prog_bar=True)

    def configure_optimizers(self):
        opt = self.optimizer(self.model.parameters())
        if self.scheduler is None:
            return opt
        return {"optimizer": opt, "lr_scheduler": {"scheduler": self.scheduler(opt), "monitor": "val/loss"}}


# the loggers of Lightning's notes to its user (the accelerators it found, tips for its products)
_LIGHTNING_NOTES = ("pytorch_lightning.utilities.rank_zero", "lightning_fabric.utilities.rank_zero")


@contextlib.contextmanager
def _quiet_lightning() -> Iterator[None]:
    """Lightning's notes and its own deprecations kept out of the stage's log, which holds the
    fit's result; its warnings about the fit itself still show."""
    loggers = [logging.getLogger(name) for name in _LIGHTNING_NOTES]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.WARNING)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\)", category=Warning)
            yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)


def window_tensors(flights: Sequence[Flight], horizon: int, stride: int = 1, dtype=torch.float32) -> TensorDataset:
    """Windows of all flights as ``(ỹ_0 (N, 12), u (N, H, 4), ỹ_1..H (N, H, 12))``."""
    parts = []
    for f in flights:
        y0, u, y = windows(f, horizon)
        parts.append((y0[::stride], u[::stride], y[::stride]))
    y0 = torch.from_numpy(np.concatenate([p[0] for p in parts]))
    u = torch.from_numpy(np.concatenate([p[1] for p in parts]))
    y = torch.from_numpy(np.concatenate([p[2] for p in parts]))
    return TensorDataset(to_tilde(y0).to(dtype), u.to(dtype), to_tilde(y).to(dtype))


def _statistics(flights: Sequence[Flight], model: SequenceModel) -> tuple[Tensor, Tensor, Tensor]:
    """Outputs, inputs, and the one-step changes the network has to predict: the increment
    of the output, or for phys_res what the physics step misses of it."""
    yt = [to_tilde(torch.from_numpy(f.y)) for f in flights]
    if model.physics is not None:
        with torch.no_grad():
            d = torch.cat([y[1:] - to_tilde(model.physics.double()(torch.from_numpy(f.y[:-1]), torch.from_numpy(f.u[:-1])))
                           for y, f in zip(yt, flights)])
    else:
        d = torch.cat([y[1:] - y[:-1] for y in yt])
    return torch.cat(yt).float(), torch.from_numpy(np.concatenate([f.u for f in flights])).float(), d.float()


def train_model(
    network: dict[str, Any],
    flights: Sequence[Flight],
    out: Path,
    *,
    physics: PhysicsStep | None = None,
    optimizer: Callable | None = None,
    scheduler: Callable | None = None,
    horizon: int = 50,
    horizon_decay: float = 0.0,
    stride: int = 1,
    batch_size: int = 512,
    epochs: int = 80,
    patience: int = 8,
    seed: int = 0,
    val_runs: Sequence[int] = (4,),
    log_dir: Path | None = None,
    accelerator: str = "auto",
    devices: int | str = 1,
    compile: bool = True,
    threads: int = 1,
    progress: bool | None = None,
) -> dict[str, Any]:
    """Train one model and save its checkpoint to ``out``.

    Args:
        network: ``{"name": key, "options": {...}}`` of a network of
            :mod:`~nanosysid.models.components`; built after seeding, so the same seed gives
            the same initial weights.
        flights: The training flights; those whose run is in ``val_runs`` validate.
        physics: The physics base of a physics + residual model.
        optimizer, scheduler, horizon_decay: See :class:`SysIdModule`.
        horizon, stride: Windows of ``horizon`` samples, every ``stride``-th start.
        epochs, patience: At most ``epochs``; early stopping after ``patience`` without a
            better validation loss.
        log_dir: Where dvclive writes the per-epoch metrics (none if None).
        compile: Run a physics base compiled (:meth:`SequenceModel.compile_base`); its bytes
            differ from the eager one's by rounding, so the trained weights do too.
        threads: torch's threads for the whole fit, whatever the caller's count (restored
            after): the count splits sums, so it is part of what sets the weights' bytes.
        progress: Lightning's progress bar; None: where the stage's error stream is a terminal
            (not in a log file, where its redraws would be most of the lines).

    Returns:
        A summary (epochs run, best validation loss, parameter count).
    """
    progress = sys.stderr.isatty() if progress is None else bool(progress)
    with torch_threads(int(threads)), _quiet_lightning():
        pl.seed_everything(int(seed), workers=True, verbose=False)
        torch.use_deterministic_algorithms(True)
        val_runs = set(val_runs)
        fit_f = [f for f in flights if f.run not in val_runs]
        val_f = [f for f in flights if f.run in val_runs]
        if not fit_f or not val_f:
            raise ConfigError(f"train: need flights both for fitting and for validation (val_runs {sorted(val_runs)}; "
                              f"runs present: {sorted({f.run for f in flights})})")
        model = build_model(network, physics)
        model.set_statistics(*_statistics(fit_f, model))
        if compile:
            model.compile_base(setting="train.compile")
        ds_fit = window_tensors(fit_f, int(horizon), int(stride))
        ds_val = window_tensors(val_f, int(horizon), int(stride))
        # each batch taken with one index per tensor, not one item at a time and stacked: the
        # sampler DataLoader's shuffle=True builds, and the loader drawing its seed from the same
        # generator first, give the same batches
        gen = torch.Generator().manual_seed(int(seed))
        dl_fit = DataLoader(ds_fit, batch_size=None, generator=gen,
                            sampler=BatchSampler(RandomSampler(ds_fit, generator=gen), int(batch_size), drop_last=False))
        dl_val = DataLoader(ds_val, batch_size=None, sampler=BatchSampler(SequentialSampler(ds_val), 4096, drop_last=False))
        module = SysIdModule(model, optimizer=optimizer, scheduler=scheduler, horizon_decay=horizon_decay)
        logger = False
        if log_dir is not None:
            from dvclive.lightning import DVCLiveLogger

            logger = DVCLiveLogger(dir=str(log_dir), save_dvc_exp=False, dvcyaml=None, report=None)
        stop = pl.callbacks.EarlyStopping("val/loss", patience=int(patience), mode="min")
        # the untrained model is a candidate too: phys_res starts as the physics model, and
        # training never hands back something worse on the validation flights than its start
        with torch.no_grad(), quiet_tracing():
            start = float(np.mean([module.loss(b).item() for b in dl_val]))
        best = _KeepBest(start, model)
        from lightning_fabric.utilities.exceptions import MisconfigurationException

        try:
            trainer = pl.Trainer(
                max_epochs=int(epochs), accelerator=accelerator, devices=devices, deterministic=True, logger=logger,
                # tqdm's bar, as the other stages': rich's redraws from a thread of its own, also into a log file
                callbacks=[stop, best] + ([pl.callbacks.TQDMProgressBar()] if progress else []),
                enable_checkpointing=False, enable_progress_bar=progress,
                enable_model_summary=False, num_sanity_val_steps=0,
                # dvclive logs each epoch; Lightning's step logging would warn of short epochs
                log_every_n_steps=max(1, min(50, len(dl_fit))),
            )
        except MisconfigurationException as e:
            # Lightning's word for an accelerator or a device count this machine does not have
            first = str(e).split(". ")[0].strip("`")
            raise ConfigError(f"train: trainer.accelerator={accelerator}, trainer.devices={devices}: {first} on this "
                              "machine; set trainer.accelerator=auto (or cpu)") from None
        with quiet_tracing():  # the training graph (with gradients) is traced at the first batch
            trainer.fit(module, dl_fit, dl_val)
        # a diverged run is no model: its best epoch would silently be the untrained start
        if best.last is not None and not (best.last <= DIVERGED * start):
            raise ConfigError(f"train: training diverged (validation loss {best.last:.4g} after epoch "
                              f"{trainer.current_epoch}, {start:.4g} untrained); lower the learning rate (the "
                              f"model's optimizer.lr, now {getattr(optimizer, 'keywords', {}).get('lr', 'the default')}) "
                              "or check the data; no model was written")
        model.load_state_dict(best.state)
        model.cpu()
        n_params = sum(p.numel() for p in model.parameters() if p.requires_grad)
        summary = {"epochs": trainer.current_epoch, "best_val_loss": best.value, "params": n_params,
                   "fit_windows": len(ds_fit), "val_windows": len(ds_val)}
        save_checkpoint(model, network, out, extra=summary)
        log.info("trained %s: %s", network["name"], summary)
        return summary


DIVERGED = 10.0  # a last validation loss this many times the untrained one is a diverged run


class _KeepBest(pl.Callback):
    """Keep the weights of the epoch with the lowest validation loss (in memory)."""

    def __init__(self, value: float, model: SequenceModel) -> None:
        self.value = value
        self.last: float | None = None  # the last epoch's validation loss
        self.state = {k: t.detach().cpu().clone() for k, t in model.state_dict().items()}

    def on_validation_epoch_end(self, trainer, module) -> None:
        v = float(trainer.callback_metrics["val/loss"])
        self.last = v
        if v < self.value:
            self.value = v
            self.state = {k: t.detach().cpu().clone() for k, t in module.model.state_dict().items()}


def network_spec(m: dict[str, Any]) -> dict[str, Any]:
    """``{"name", "options"}`` of a learned model's ``network`` block (what its checkpoint stores)."""
    net = dict(m["network"])
    return {"name": net.pop("name"), "options": net}


def physics_base(m: dict[str, Any]) -> PhysicsStep | None:
    """The physics step of a ``physics`` block (physics + residual), k_F and k_M identified."""
    p = m.get("physics")
    if p is None:
        return None
    v = identified_vehicle(Vehicle.from_mapping(p["vehicle"]), p.get("identified"))
    return PhysicsStep(v, dt=float(p["dt"]), substeps=int(p["substeps"]), angular_dynamics=False)


def optimiser_parts(optimizer: Mapping[str, Any], scheduler: Mapping[str, Any] | None, where: str = "train"):
    """The optimiser and scheduler factories of a model's config blocks (Hydra ``_target_``
    blocks with ``_partial_: true``), tried once on a probe parameter so that a bad argument
    (``lr=abc``, a keyword the class does not take) is one error, naming ``where``, before
    training starts."""
    try:
        make_optimizer = instantiate(dict(optimizer))
        probe = make_optimizer([torch.zeros(1, requires_grad=True)])
        make_scheduler = instantiate(dict(scheduler)) if scheduler else None
        if make_scheduler is not None:
            make_scheduler(probe)
    except Exception as e:  # Hydra's InstantiationException, or the class's own TypeError / ValueError
        first = str(e).strip().splitlines()[-1] if str(e).strip() else type(e).__name__
        raise ConfigError(f"{where}.optimizer / scheduler: cannot build them ({first})") from None
    return make_optimizer, make_scheduler
