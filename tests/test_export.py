"""Export: the C generator on known weights and known arithmetic, ONNX against PyTorch, and a
small model end to end on the emulated STM32F405."""

import shutil
import subprocess

import numpy as np
import pytest
import torch

from nanosysid import synthetic
from nanosysid.export import mcu
from nanosysid.errors import ToolchainError
from nanosysid.export.cgen import Tracer, physics_step_scalar
from nanosysid.export.csource import learned_source
from nanosysid.export.steps import augmented_step, check_inputs, export_onnx, learned_step, onnx_outputs, physics_step
from nanosysid.models.learned import LearnedPredictor, build_model
from nanosysid.models.physics import PhysicsStep
from nanosysid.rollout import StepPredictor
from nanosysid.vehicle import Vehicle

MAIN = r"""
#include <stdio.h>
#include "nsi_inputs.h"
#include "nsi_model.h"
static float state[NSI_NSTATE];
int main(void)
{
    float out[NSI_NY];
    nsi_init(nsi_y_in[0], state);
    for (int k = 0; k < NSI_K; ++k) {
        nsi_step(nsi_y_in[k], nsi_u_in[k], state, out);
        for (int i = 0; i < NSI_NY; ++i)
            printf("%.9g\n", (double)out[i]);
    }
    return 0;
}
"""


def small_model(arch, seed=0):
    """A learned model with small layers and known, seeded weights and statistics."""
    torch.manual_seed(seed)
    vehicle = Vehicle()
    physics = PhysicsStep(vehicle) if arch == "phys_res" else None
    net = {"name": "lstm", "options": {"hidden": 4, "init_hidden": 3}} if arch == "lstm" else \
        {"name": "mlp", "options": {"hidden": [6, 5]}}
    m = build_model(net, physics)
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in m.parameters():
            p.copy_(0.5 * torch.randn(p.shape, generator=g))
        m.y_mean.copy_(0.1 * torch.randn(12, generator=g))
        m.y_std.copy_(1.0 + torch.rand(12, generator=g))
        m.u_mean.fill_(2000.0)
        m.u_std.fill_(300.0)
        m.d_std.copy_(0.01 * (1.0 + torch.rand(12, generator=g)))
    return m.eval()


def flight_inputs(ex, n=12):
    f = synthetic.synthetic_flights(["melon_s_run1"], 200, seed=3)[0]
    return ex.outputs_in(f.y[100:100 + n]), f.u[100:100 + n].astype(np.float32), f


# the step's own output fed back as its next input: a multi-step prediction, as the benchmark scores it
MAIN_ROLLOUT = r"""
#include <stdio.h>
#include "nsi_inputs.h"
#include "nsi_model.h"
static float state[NSI_NSTATE];
int main(void)
{
    float y[NSI_NY], out[NSI_NY];
    for (int i = 0; i < NSI_NY; ++i)
        y[i] = nsi_y_in[0][i];
    nsi_init(y, state);
    for (int k = 0; k < NSI_K; ++k) {
        nsi_step(y, nsi_u_in[k], state, out);
        for (int i = 0; i < NSI_NY; ++i) {
            printf("%.9g\n", (double)out[i]);
            y[i] = out[i];
        }
    }
    return 0;
}
"""


def run_on_host(tmp_path, c_model, y_in, u_in, main=MAIN):
    mcu.write_sources(tmp_path, c_model, y_in, u_in)
    (tmp_path / "main.c").write_text(main)
    subprocess.run(["gcc", "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-o", "host", "main.c", "model.c", "-lm"],
                   cwd=tmp_path, check=True, capture_output=True)
    out = subprocess.run([str(tmp_path / "host")], capture_output=True, text=True, check=True).stdout.split()
    return np.array(out, dtype=np.float64).reshape(len(y_in), -1)


def test_tracer_folds_constants_and_counts_each_operation():
    tr = Tracer()
    x, y, z = (tr.input(n) for n in "xyz")
    out = [x * y + 1.0 * z, 0.0 * x + z, (2.0 * 3.0) * x, x - 0.0, z / y]
    lines, counts = tr.live(out)
    assert out[1] is z and out[3] is x  # nothing emitted for 0 * x + z and x - 0
    assert counts == {"mul": 2, "add": 1, "div": 1}
    assert "6.000000000e+00f * x" in "\n".join(lines)
    # what no output uses is not emitted
    unused = x * z
    assert all(unused.ref not in line for line in tr.live(out)[0])


def test_scalar_physics_step_is_the_torch_step():
    v = Vehicle()
    rng = np.random.default_rng(0)
    y = rng.normal(size=13)
    y[6:10] /= np.linalg.norm(y[6:10])
    u = rng.uniform(1000, 2500, 4)
    for angular in (False, True):
        ref = PhysicsStep(v, substeps=2, angular_dynamics=angular)(torch.tensor(y)[None], torch.tensor(u)[None])[0]
        got = physics_step_scalar(list(y), list(u), dt=0.01, substeps=2, angular_dynamics=angular,
                                  **v.dynamics_kwargs())
        assert np.allclose(got, ref.numpy(), rtol=0, atol=1e-14)


@pytest.mark.parametrize("arch", ["residual", "phys_res", "lstm"])
def test_generated_c_holds_the_weights_and_computes_the_torch_step(tmp_path, arch):
    m = small_model(arch)
    c = learned_source(arch, m)
    first = (m.network.cell.weight_ih if arch == "lstm" else m.network.mlp[0].weight).detach().numpy().reshape(-1)
    assert f"{first[0]:.9e}f" in c.source and "malloc" not in c.source
    assert all(line.startswith("#include <math.h>") or "<stdint.h>" in line or "nsi_model.h" in line
               for line in c.source.splitlines() if line.startswith("#include"))
    ex = learned_step(LearnedPredictor(m), arch)
    y_in, u_in, _ = flight_inputs(ex)
    got = run_on_host(tmp_path, c, y_in, u_in)
    ref = ex.teacher_forced(y_in, u_in)
    scale = np.maximum(np.abs(ref).max(axis=0), 1e-6)
    assert (np.abs(got - ref) / scale).max() < 1e-5


@pytest.mark.parametrize("arch", ["physics", "phys_res", "lstm"])
def test_generated_c_rollout_of_50_steps_follows_the_torch_prediction(tmp_path, arch):
    """The C step, fed its own outputs for 50 steps, against the torch model's 50-step
    prediction in double precision: float32 rounding must not build up over the horizon."""
    from nanosysid.models.learned import to_tilde

    if arch == "physics":
        predict = StepPredictor(PhysicsStep(Vehicle()))
        ex = physics_step(predict, "physics")
    else:
        predict = LearnedPredictor(small_model(arch))
        ex = learned_step(predict, arch)
    f = synthetic.synthetic_flights(["melon_s_run1"], 200, seed=3)[0]
    y_in, u_in = ex.outputs_in(f.y[100:150]), f.u[100:150].astype(np.float32)
    got = run_on_host(tmp_path, ex.c, y_in, u_in, main=MAIN_ROLLOUT)
    ref = predict(f.y[100:101], f.u[None, 100:150].astype(np.float64))[0]
    ref = ref if ex.ny == 13 else to_tilde(torch.from_numpy(ref)).numpy()
    assert got.shape == ref.shape == (50, ex.ny)
    span = np.maximum(ref.max(axis=0) - ref.min(axis=0), 1e-3)
    assert (np.abs(got - ref) / span).max() < 1e-4


def test_generated_physics_c_computes_the_torch_step(tmp_path):
    ex = physics_step(StepPredictor(PhysicsStep(Vehicle())), "physics")
    y_in, u_in, _ = flight_inputs(ex)
    got = run_on_host(tmp_path, ex.c, y_in, u_in)
    ref = ex.teacher_forced(y_in, u_in)
    assert np.abs(got - ref).max() / np.abs(ref).max() < 1e-6
    assert ex.c.flops == sum(ex.c.notes["operations"].values()) and 250 < ex.c.flops < 500


@pytest.mark.parametrize("arch", ["residual", "phys_res", "lstm"])
def test_onnx_computes_the_torch_step(tmp_path, arch):
    ex = learned_step(LearnedPredictor(small_model(arch)), arch)
    flights = synthetic.synthetic_flights(["melon_s_run1", "melon_s_run2"], 200, seed=4)
    inputs = check_inputs(ex, flights, 64, seed=0)
    files = export_onnx(ex, tmp_path)
    with torch.no_grad():
        ref = ex.step(*(torch.from_numpy(inputs[k]) for k in (["y", "u", "h", "c"] if arch == "lstm" else ["y", "u"])))
    ref = ref if isinstance(ref, tuple) else (ref,)
    got = onnx_outputs(files[0], inputs)
    assert len(got) == len(ref)
    for g, r in zip(got, ref):
        assert np.abs(g - r.numpy()).max() < 1e-5
    if arch == "lstm":
        assert inputs["h"].shape == (64, 4) and np.abs(inputs["h"]).max() > 0


def toolchain_or_skip():
    try:
        mcu.require_toolchain()
    except ToolchainError as e:
        pytest.skip(str(e))


def test_small_model_runs_on_the_emulated_stm32(tmp_path):
    toolchain_or_skip()
    m = small_model("lstm")
    ex = learned_step(LearnedPredictor(m), "lstm")
    y_in, u_in, f = flight_inputs(ex, n=8)
    mcu.write_sources(tmp_path, ex.c, y_in, u_in)
    size = mcu.build(tmp_path)
    run = mcu.run(tmp_path, ex.ny)
    ref = ex.teacher_forced(y_in, u_in)
    assert run.outputs.shape == (8, 12) and mcu.range_relative_diff(run.outputs, ref, ex.outputs_in(f.y)) < 1e-5
    assert run.steps == 8
    # 4 gates x 4 units x (16 + 4) inputs: some hundreds of multiply-adds, a few instructions each
    assert 500 < run.instructions_per_step < 5000 and run.instructions_total > 8 * run.instructions_per_step
    assert 0 < size["text"] < 8192 and size["stack"] > 0
    # the count is deterministic
    assert mcu.run(tmp_path, ex.ny).instructions_per_step == run.instructions_per_step


def test_mcu_difference_is_relative_to_each_outputs_range():
    """Height between 1.0 and 2.0 m (range 1 m) off by 1e-6 m: 1e-6, not 1e-6 / 2.0 as against
    its largest value; qw between 0.98 and 1.0 off by 1e-7: 5e-6, not 1e-7; a channel that
    never moves is judged in its own units."""
    samples = np.array([[1.0, 0.98, 3.0], [2.0, 1.0, 3.0], [1.5, 0.99, 3.0]])
    ref = np.array([[1.5, 0.99, 3.0]])
    assert mcu.range_relative_diff(ref + [[1e-6, 0.0, 0.0]], ref, samples) == pytest.approx(1e-6)
    assert mcu.range_relative_diff(ref + [[0.0, 1e-7, 0.0]], ref, samples) == pytest.approx(5e-6)
    assert mcu.range_relative_diff(ref + [[0.0, 0.0, 2e-7]], ref, samples) == pytest.approx(2e-7)


def test_missing_toolchain_is_one_clear_message(monkeypatch):
    real = shutil.which
    monkeypatch.setattr(shutil, "which", lambda t: None if t == "qemu-system-arm" else real(t))
    with pytest.raises(ToolchainError, match="(?s)missing [^:]*qemu-system-arm.*apt-get install -y --no-install-recommends"):
        mcu.require_toolchain()


@pytest.mark.parametrize("integrated", [(True, True, True), (False, True, False)])
def test_discovered_model_exports_to_c_and_onnx(tmp_path, integrated):
    from nanosysid.discover.model import AugmentedPredictor, AugmentedStep

    effects = {"induced_drag": [1.8e-6, 1.0e-6], "quadratic_drag": [1.5e-3, 3.0e-3], "cg_offset": [1.5e-3, -1.0e-3],
               "rotor_spread": [0.01, -0.02, 0.005], "rotor_gyro": [3.9e-8], "drag_moment": [2e-4],
               "induced_rate_damping": [1e-9, 2e-9], "term:tau_x:v_y*w_z": [1e-5], "term:F_z:T*z": [-0.01]}
    step = AugmentedStep(Vehicle(), list(effects), [c for v in effects.values() for c in v], integrated=integrated)
    ex = augmented_step(AugmentedPredictor(step, delay=0.03), "discovered")
    assert ex.nu == 8 and "#define NSI_NU 8" in ex.c.header and "fabsf(" in ex.c.source
    _, _, f = flight_inputs(ex)
    u_all = ex.inputs_in(f)
    assert u_all.shape == (len(f), 8)
    assert np.allclose(u_all[10, :4], f.u[13], rtol=1e-6)  # read 30 ms (3 samples) later
    y_in, u_in = ex.outputs_in(f.y[100:112]), u_all[100:112]
    got = run_on_host(tmp_path, ex.c, y_in, u_in)
    ref = ex.teacher_forced(y_in, u_in)
    assert np.abs(got - ref).max() / np.abs(ref).max() < 1e-6
    # about a held axis the C step keeps the angular velocity it was given
    held = [10 + i for i, on in enumerate(integrated) if not on]
    assert np.allclose(got[:, held], y_in[:, held], rtol=1e-6, atol=1e-7)
    inputs = check_inputs(ex, [f], 32, seed=0)
    out = onnx_outputs(export_onnx(ex, tmp_path)[0], inputs)[0]
    with torch.no_grad():
        assert np.abs(out - ex.step(torch.from_numpy(inputs["y"]), torch.from_numpy(inputs["u"])).numpy()).max() < 1e-5
