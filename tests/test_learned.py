"""Learned models: shapes, the zero-initialised residual, training, determinism, checkpoints."""

import dataclasses

import numpy as np
import pytest
import torch

from nanosysid import benchmark, so3, synthetic
from nanosysid.models.learned import ARCHS, LearnedPredictor, build_model, from_tilde, load_model, save_checkpoint, to_tilde
from nanosysid.models.training import SysIdModule, train_model, window_tensors
from nanosysid.vehicle import Vehicle

VEHICLE = {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(Vehicle()).items()}
HPARAMS = {
    "residual": {"arch": "residual", "hidden": [120, 120]},
    "phys_res": {"arch": "phys_res", "hidden": [120, 120], "vehicle": VEHICLE, "dt": 0.01, "substeps": 1},
    "lstm": {"arch": "lstm", "lstm_hidden": 62, "init_hidden": 32},
}
PAPER_PARAMS = {"residual": 18_500, "phys_res": 18_500, "lstm": 24_700}
QUICK = {"horizon": 20, "stride": 10, "batch_size": 64, "epochs": 3, "lr": 3e-3, "patience": 5, "seed": 0,
         "val_runs": [3]}


@pytest.fixture(scope="module")
def flights():
    names = [f"chirp_x_run{k}" for k in (1, 2, 3)]
    return synthetic.synthetic_flights(names, 400, noise=1e-3, seed=4)


@pytest.mark.parametrize("arch", ARCHS)
def test_parameter_counts_close_to_the_paper(arch):
    n = sum(p.numel() for p in build_model(HPARAMS[arch]).parameters() if p.requires_grad)
    assert abs(n / PAPER_PARAMS[arch] - 1) < 0.10, n


@pytest.mark.parametrize("arch", ARCHS)
def test_one_step_and_multi_step_shapes(arch, flights):
    model = build_model(HPARAMS[arch]).double()
    y0, u, _ = benchmark.windows(flights[0], 7)
    yt0 = to_tilde(torch.from_numpy(y0[:5]))
    state = model.init_state(yt0)
    yt1, _ = model.step(yt0, torch.from_numpy(u[:5, 0]), state)
    assert yt1.shape == (5, 12)
    assert model.rollout(yt0, torch.from_numpy(u[:5])).shape == (5, 7, 12)
    assert LearnedPredictor(model)(y0[:5], u[:5]).shape == (5, 7, 13)


def test_phys_res_starts_as_the_physics_model(flights):
    model = build_model(HPARAMS["phys_res"])
    ds = window_tensors(flights, 10)
    model.set_statistics(ds.tensors[0], ds.tensors[1].reshape(-1, 4), ds.tensors[0][1:] - ds.tensors[0][:-1])
    model.net[-1].bias.data.zero_()  # (already zero: the residual head starts at zero)
    assert not model.net[-1].weight.any()
    y0, u, _ = benchmark.windows(flights[0], 10)
    ours = LearnedPredictor(model)(y0[:50], u[:50])
    phys = benchmark.model("physics")(y0[:50], u[:50])
    assert np.allclose(ours, phys, atol=1e-9)


def test_representation_round_trip(flights):
    y = torch.from_numpy(flights[0].y)
    back = from_tilde(to_tilde(y))
    q = so3.quat_canonical(y[:, 6:10])  # the rotation vector keeps the rotation, not the sign
    assert torch.allclose(back[:, 6:10], q, atol=1e-12)
    assert torch.equal(back[:, :6], y[:, :6]) and torch.equal(back[:, 10:], y[:, 10:])


@pytest.mark.parametrize("arch", ARCHS)
def test_short_training_lowers_the_loss_and_is_deterministic(arch, flights, tmp_path):
    hp = HPARAMS[arch]
    s1 = train_model(hp, QUICK, flights, tmp_path / "a.pt", progress=False)
    s2 = train_model(hp, QUICK, flights, tmp_path / "b.pt", progress=False)
    m1, c1 = load_model(tmp_path / "a.pt")
    m2, _ = load_model(tmp_path / "b.pt")
    for (k, a), b in zip(m1.state_dict().items(), m2.state_dict().values()):
        assert torch.equal(a, b), k
    assert s1 == s2
    assert (tmp_path / "a.pt").read_bytes() == (tmp_path / "b.pt").read_bytes()  # same bytes: DVC's cache relies on it
    # the trained model's validation loss is below the untrained one's
    untrained = build_model(hp)
    untrained.load_state_dict({k: v for k, v in m1.state_dict().items() if k.endswith(("mean", "std"))}, strict=False)
    for runs in ((1, 2), (3,)):  # the fitted flights and the validation flight
        ds = window_tensors([f for f in flights if f.run in runs], QUICK["horizon"], QUICK["stride"])
        batch = tuple(t.float() for t in ds.tensors)
        with torch.no_grad():
            assert SysIdModule(m1.float()).loss(batch) < SysIdModule(untrained.float()).loss(batch)
    assert c1["extra"]["best_val_loss"] == s1["best_val_loss"]


def test_checkpoint_round_trip_is_weights_only(tmp_path):
    model = build_model(HPARAMS["lstm"])
    model.y_std.fill_(2.0)
    save_checkpoint(model, HPARAMS["lstm"], tmp_path / "m.pt")
    raw = torch.load(tmp_path / "m.pt", weights_only=True)  # no pickled objects inside
    assert raw["hparams"] == HPARAMS["lstm"]
    back, _ = load_model(tmp_path / "m.pt")
    for (k, a), b in zip(model.state_dict().items(), back.state_dict().values()):
        assert torch.equal(a, b), k
    assert isinstance(benchmark.model(str(tmp_path / "m.pt")), LearnedPredictor)


def test_no_validation_flights_is_one_clear_error(flights, tmp_path):
    from nanosysid.config import ConfigError

    with pytest.raises(ConfigError, match=r"val_runs \[7\]; runs present: \[1, 2, 3\]"):
        train_model(HPARAMS["residual"], {**QUICK, "val_runs": [7]}, flights, tmp_path / "x.pt", progress=False)
