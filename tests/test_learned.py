"""Learned models: shapes, the zero-initialised residual, training, determinism, checkpoints."""

import functools
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from nanosysid import numerics, predictors, protocol, so3, synthetic
from nanosysid.models.learned import (LearnedPredictor, build_model, content_hash, from_tilde, load_checkpoint,
                                      save_checkpoint, to_tilde)
from nanosysid.models.physics import PhysicsStep
from nanosysid.models.training import SysIdModule, train_model, window_tensors
from nanosysid.vehicle import Vehicle

# the networks and physics bases of the three learned models of conf/model/
NETWORKS = {
    "residual": {"name": "mlp", "options": {"hidden": [120, 120]}},
    "phys_res": {"name": "mlp", "options": {"hidden": [120, 120], "zero_init": True}},
    "lstm": {"name": "lstm", "options": {"hidden": 62, "init_hidden": 32}},
}
ARCHS = tuple(NETWORKS)


def physics(arch):
    return PhysicsStep(Vehicle(), dt=0.01, substeps=1) if arch == "phys_res" else None


def make(arch):
    return build_model(NETWORKS[arch], physics(arch))


PAPER_PARAMS = {"residual": 18_500, "phys_res": 18_500, "lstm": 24_700}
QUICK = {"horizon": 20, "stride": 10, "batch_size": 64, "epochs": 3, "patience": 5, "seed": 0, "val_runs": [3],
         "optimizer": functools.partial(torch.optim.Adam, lr=3e-3)}


@pytest.fixture(scope="module")
def flights():
    names = [f"chirp_x_run{k}" for k in (1, 2, 3)]
    return synthetic.synthetic_flights(names, 400, noise=1e-3, seed=4)


@pytest.mark.parametrize("arch", ARCHS)
def test_parameter_counts_close_to_the_paper(arch):
    n = sum(p.numel() for p in make(arch).parameters() if p.requires_grad)
    assert abs(n / PAPER_PARAMS[arch] - 1) < 0.10, n


@pytest.mark.parametrize("arch", ARCHS)
def test_one_step_and_multi_step_shapes(arch, flights):
    model = make(arch).double()
    y0, u, _ = protocol.windows(flights[0], 7)
    yt0 = to_tilde(torch.from_numpy(y0[:5]))
    state = model.init_state(yt0)
    yt1, _ = model.step(yt0, torch.from_numpy(u[:5, 0]), state)
    assert yt1.shape == (5, 12)
    assert model.rollout(yt0, torch.from_numpy(u[:5])).shape == (5, 7, 12)
    assert LearnedPredictor(model)(y0[:5], u[:5]).shape == (5, 7, 13)


def test_phys_res_starts_as_the_physics_model(flights):
    model = make("phys_res")
    ds = window_tensors(flights, 10)
    model.set_statistics(ds.tensors[0], ds.tensors[1].reshape(-1, 4), ds.tensors[0][1:] - ds.tensors[0][:-1])
    y0, u, _ = protocol.windows(flights[0], 10)
    ours = LearnedPredictor(model)(y0[:50], u[:50])
    phys = predictors.predictor("physics")(y0[:50], u[:50])
    assert np.allclose(ours, phys, atol=1e-9)


def test_the_compiled_physics_base_is_the_eager_one_to_rounding_at_any_batch(flights):
    """phys_res trains with its physics base compiled: one graph for every batch size, forward
    and backward. Against the eager base (ATen's kernels, not inductor's): the same prediction
    and the same gradient within float32 rounding, and a window's prediction the same bytes in a
    batch of 3 as in one of 6 (what one kernel for every batch size must keep; a batch of one
    is a graph of its own, dynamo specialises that size)."""
    model = make("phys_res")
    eager = model.base
    model.compile_base()
    y0, u, _ = protocol.windows(flights[0], 2)
    yt = to_tilde(torch.from_numpy(y0[:64])).float()
    uk = torch.from_numpy(u[:64, 0]).float()
    for n in (64, 5):
        a = yt[:n].clone().requires_grad_(True)
        b = yt[:n].clone().requires_grad_(True)
        out_c, out_e = model._compiled_base(a, uk[:n]), eager(b, uk[:n])
        assert torch.allclose(out_c, out_e, rtol=1e-5, atol=1e-6)
        assert not torch.equal(out_c, a)  # the physics moved the state: a base that passed ỹ through would fail
        w = torch.linspace(-1, 1, 12)
        (out_c * w).sum().backward()
        (out_e * w).sum().backward()
        assert torch.allclose(a.grad, b.grad, rtol=1e-4, atol=1e-5)
    # the graph training runs (inputs that take a gradient), at other places in its vectorised loops
    alone, among = yt[3:6].clone().requires_grad_(True), yt[:6].clone().requires_grad_(True)
    assert torch.equal(model._compiled_base(alone, uk[3:6]), model._compiled_base(among, uk[:6])[3:6])


@pytest.mark.slow
@pytest.mark.skipif(not numerics.V3_FLAGS <= (numerics.cpu_flags() or frozenset()), reason="no AVX2 on this CPU")
def test_the_compiled_physics_base_keeps_its_bounds_at_the_train_stages_level(venv_env):
    """The test above in a process pinned as the train stage pins itself (AVX2 vector code)."""
    code = "\n".join([
        "from nanosysid import numerics",
        "numerics.pin(numerics.STAGE_LEVELS['stages.train'])",
        "import torch",
        "assert torch.backends.cpu.get_cpu_capability() == 'AVX2'",
        "import test_learned as t",
        "from nanosysid import synthetic",
        "flights = synthetic.synthetic_flights([f'chirp_x_run{k}' for k in (1, 2, 3)], 400, noise=1e-3, seed=4)",
        "t.test_the_compiled_physics_base_is_the_eager_one_to_rounding_at_any_batch(flights)",
    ])
    r = subprocess.run([sys.executable, "-c", code], cwd=Path(__file__).parent, env=venv_env, capture_output=True,
                       text=True)
    assert r.returncode == 0, r.stderr[-3000:]


def test_representation_round_trip(flights):
    y = torch.from_numpy(flights[0].y)
    back = from_tilde(to_tilde(y))
    q = so3.quat_canonical(y[:, 6:10])  # the rotation vector keeps the rotation, not the sign
    assert torch.allclose(back[:, 6:10], q, atol=1e-12)
    assert torch.equal(back[:, :6], y[:, :6]) and torch.equal(back[:, 10:], y[:, 10:])


def test_the_loss_weighs_step_h_by_the_horizon_decay():
    """Hand-worked: 3 steps, errors of 1 and 2 output standard deviations at steps 1 and 3 of one
    output of 12. Unweighted, (1 + 4) / 36. With decay ln 2 the steps weigh 1, 1/2, 1/4, scaled to
    a mean of 1: 12/7, 6/7, 3/7, so (12/7 * 1 + 3/7 * 4) / 36 = 2/21."""

    class Still(torch.nn.Module):
        y_std = torch.full((12,), 2.0)

        def rollout(self, yt0, u):
            return torch.zeros(yt0.shape[0], u.shape[1], 12)

    target = torch.zeros(5, 3, 12)
    target[:, 0, 4], target[:, 2, 4] = 2.0, -4.0
    batch = (torch.zeros(5, 12), torch.zeros(5, 3, 4), target)
    assert SysIdModule(Still()).loss(batch).item() == pytest.approx(5 / 36, rel=1e-6)
    assert SysIdModule(Still(), horizon_decay=np.log(2)).loss(batch).item() == pytest.approx(2 / 21, rel=1e-6)


@pytest.mark.parametrize("arch", ARCHS)
def test_short_training_lowers_the_loss_and_is_deterministic(arch, flights, tmp_path):
    s1 = train_model(NETWORKS[arch], flights, tmp_path / "a.pt", physics=physics(arch), progress=False, **QUICK)
    s2 = train_model(NETWORKS[arch], flights, tmp_path / "b.pt", physics=physics(arch), progress=False, **QUICK)
    m1, c1 = load_checkpoint(tmp_path / "a.pt")
    m2, _ = load_checkpoint(tmp_path / "b.pt")
    for (k, a), b in zip(m1.state_dict().items(), m2.state_dict().values()):
        assert torch.equal(a, b), k
    assert s1 == s2
    assert (tmp_path / "a.pt").read_bytes() == (tmp_path / "b.pt").read_bytes()  # same bytes: DVC's cache relies on it
    # the trained model's validation loss is below the untrained one's
    untrained = make(arch)
    untrained.load_state_dict({k: v for k, v in m1.state_dict().items() if k.endswith(("mean", "std"))}, strict=False)
    for runs in ((1, 2), (3,)):  # the fitted flights and the validation flight
        ds = window_tensors([f for f in flights if f.run in runs], QUICK["horizon"], QUICK["stride"])
        batch = tuple(t.float() for t in ds.tensors)
        with torch.no_grad():
            assert SysIdModule(m1.float()).loss(batch) < SysIdModule(untrained.float()).loss(batch)
    assert c1["extra"]["best_val_loss"] == s1["best_val_loss"]


def test_the_fit_runs_on_its_own_thread_count_whatever_the_callers_and_gives_it_back(flights, tmp_path, monkeypatch):
    seen = []
    real = SysIdModule.loss

    def spy(self, batch):
        seen.append(torch.get_num_threads())
        return real(self, batch)

    monkeypatch.setattr(SysIdModule, "loss", spy)
    before = torch.get_num_threads()
    try:
        for caller in (2, 3):
            torch.set_num_threads(caller)
            train_model(NETWORKS["residual"], flights, tmp_path / f"{caller}.pt", progress=False, threads=1, **QUICK)
            assert torch.get_num_threads() == caller
    finally:
        torch.set_num_threads(before)
    assert seen and set(seen) == {1}  # the validation's start, every batch and every validation
    assert (tmp_path / "2.pt").read_bytes() == (tmp_path / "3.pt").read_bytes()


def test_checkpoint_round_trip_is_weights_only(tmp_path):
    model = make("lstm")
    model.y_std.fill_(2.0)
    save_checkpoint(model, NETWORKS["lstm"], tmp_path / "m.pt")
    raw = torch.load(tmp_path / "m.pt", weights_only=True)  # no pickled objects inside
    assert raw["network"] == NETWORKS["lstm"]
    back, _ = load_checkpoint(tmp_path / "m.pt")
    for (k, a), b in zip(model.state_dict().items(), back.state_dict().values()):
        assert torch.equal(a, b), k
    assert isinstance(predictors.predictor(str(tmp_path / "m.pt")), LearnedPredictor)


def test_no_validation_flights_is_one_clear_error(flights, tmp_path):
    from nanosysid.errors import ConfigError

    with pytest.raises(ConfigError, match=r"val_runs \[7\]; runs present: \[1, 2, 3\]"):
        train_model(NETWORKS["residual"], flights, tmp_path / "x.pt", progress=False, **{**QUICK, "val_runs": [7]})


def test_bad_checkpoints_are_one_clear_error(tmp_path):
    import pickle

    from nanosysid.errors import ConfigError, DataError

    good = tmp_path / "good.pt"
    save_checkpoint(make("residual"), NETWORKS["residual"], good)
    data = good.read_bytes()
    cases = {
        "missing.pt": (None, r"missing\.pt: no such checkpoint"),
        "truncated.pt": (data[: len(data) // 2], r"truncated\.pt: not a readable checkpoint, the file is damaged"),
        "tensor.pt": ("tensor", r"tensor\.pt: not a nanosysid model checkpoint .* holds a bare Tensor"),
        "pickled.pt": ("pickle", r"pickled\.pt: the checkpoint holds Python objects .* refused"),
        "sizes.pt": ("sizes", r"sizes\.pt: the weights do not fit the network it names \(mlp\)"),
        "nonet.pt": ("nonet", r"nonet\.pt: field 'network' is missing"),
    }
    for name, (content, message) in cases.items():
        path = tmp_path / name
        if content == "tensor":
            torch.save(torch.zeros(3), path)
        elif content == "pickle":
            path.write_bytes(pickle.dumps({"format": "x", "obj": functools.partial(print, 1)}))
            torch.save({"format": "nanosysid-model-3", "callable": functools.partial(print, 1)}, path)
        elif content in ("sizes", "nonet"):
            ckpt = torch.load(good, weights_only=True)
            if content == "sizes":
                # a checkpoint consistent with its own hash whose weights fit another network
                ckpt["network"] = {"name": "mlp", "options": {"hidden": [64, 64]}}
                ckpt["sha256"] = content_hash(ckpt["network"], ckpt["physics"], ckpt["state_dict"])
            else:
                del ckpt["network"]
            torch.save(ckpt, path)
        elif content is not None:
            path.write_bytes(content)
        with pytest.raises(DataError, match=message) as err:
            load_checkpoint(path)
        assert "weights_only=False" not in str(err.value)
    # an LSTM's checkpoint where the config names the residual MLP
    lstm = tmp_path / "lstm.pt"
    save_checkpoint(make("lstm"), NETWORKS["lstm"], lstm)
    with pytest.raises(ConfigError, match=r"lstm\.pt: holds a lstm network, but the model's config names mlp"):
        predictors.build_from_options({"kind": "learned", "checkpoint": str(lstm), "network": NETWORKS["residual"]})
    with pytest.raises(ConfigError, match=r"good\.pt: the network has no physics base, but the model's config gives one"):
        predictors.build_from_options({"kind": "learned", "checkpoint": str(good), "network": NETWORKS["phys_res"],
                                   "physics": {"dt": 0.01}})


def test_a_fit_into_a_log_file_writes_its_result_and_no_chatter(flights, tmp_path, capfd):
    """Outside a terminal (a stage under DVC), no progress bar redraws, no accelerator census,
    no tips and no deprecations of Lightning's own: the log holds what a user reads."""
    import logging

    logging.getLogger("nanosysid").setLevel(logging.INFO)
    train_model(NETWORKS["residual"], flights, tmp_path / "a.pt", **QUICK)  # progress None: stderr is no terminal here
    out, err = capfd.readouterr()
    text = out + err
    assert "\r" not in text and "it/s" not in text, text[:500]
    for chatter in ("GPU available", "TPU available", "Tip:", "Seed set", "deprecated", "log_every_n_steps"):
        assert chatter not in text, chatter
