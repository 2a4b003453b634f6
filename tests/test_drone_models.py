"""The drone-models export, read back through drone-models itself: its first_principles model,
given the exported section, must accelerate the body as the identified model does."""

import json
import math
import os
import shutil
import subprocess
import sys
import tomllib
from importlib.util import find_spec
from pathlib import Path

import pytest
import torch

from nanosysid import so3
from nanosysid.dynamics import quad_dynamics
from nanosysid.export import drone_models
from nanosysid.vehicle import Vehicle

NAME = "cf21B_500_test"
K_XY, K_Z = 2.0e-6, 1.5e-6  # induced drag, kg/rad

# In a process of its own: drone-models needs scipy's array API flag set before scipy loads.
READ_BACK = """
import json, sys
import numpy as np
from drone_models.core import parametrize
from drone_models.first_principles import dynamics
f = parametrize(dynamics, drone_model=sys.argv[1])
d = json.load(sys.stdin)
out = f(pos=np.zeros((len(d["vel"]), 3)), quat=np.array(d["quat"]), vel=np.array(d["vel"]),
        ang_vel=np.array(d["ang_vel"]), cmd=np.array(d["rpm"]))
import drone_models
print(json.dumps({"vel_dot": out[2].tolist(), "ang_vel_dot": out[3].tolist(), "library": drone_models.__file__}))
"""


@pytest.fixture(scope="module")
def library(tmp_path_factory) -> tuple[Path, Vehicle]:
    """A copy of the installed drone-models holding the exported section, as its README says."""
    spec = find_spec("drone_models")
    if spec is None:
        pytest.fail("drone-models is not installed (requirements.txt): make venv")
    root = tmp_path_factory.mktemp("drone_models")
    package = root / "drone_models"
    shutil.copytree(Path(spec.origin).parent, package, ignore=shutil.ignore_patterns("assets", "*.stl"))
    vehicle = Vehicle(mass=0.043, inertia=(2.5e-5, 2.8e-5, 4.9e-5), arm=0.035, k_f=3.7e-8, k_m=2.1e-10, gravity=9.81)
    params, held, left = drone_models.parameters(vehicle, {"induced_drag": [K_XY, K_Z], "rotor_spread": [0.01, 0.0, 0.0]})
    assert held == ["induced_drag"] and left == ["rotor_spread"]
    assert drone_models.parameters(vehicle, {}, delay=0.03)[2] == ["input_delay"]
    text = drone_models.toml_text(NAME, params, held=held, left=left, source="a test")
    assert tomllib.loads(text)[NAME]["mass"] == 0.043
    with open(package / "data" / "params.toml", "a") as f:
        f.write("\n" + text)
    with open(package / "first_principles" / "params.toml", "a") as f:
        f.write(f"\n[{NAME}]\n")
    return root, vehicle


def test_drone_models_reads_the_export_as_the_identified_model(library):
    root, vehicle = library
    g = torch.Generator().manual_seed(3)
    n = 16
    quat = torch.nn.functional.normalize(torch.randn(n, 4, generator=g, dtype=torch.float64), dim=-1)
    vel = torch.randn(n, 3, generator=g, dtype=torch.float64) * 2.0
    w = torch.randn(n, 3, generator=g, dtype=torch.float64) * 3.0
    # rotor speeds around hover whose sum is the hover sum: there the induced drag, which grows
    # with the sum, is the constant drag matrix the format holds
    hover = math.sqrt(vehicle.mass * vehicle.gravity / (4 * vehicle.k_f))
    spread = torch.randn(n, 4, generator=g, dtype=torch.float64) * 0.1
    om = hover * (1.0 + spread - spread.mean(dim=-1, keepdim=True))
    payload = {"quat": quat.tolist(), "vel": vel.tolist(), "ang_vel": w.tolist(),
               "rpm": (om * 60.0 / (2.0 * math.pi)).tolist()}
    env = dict(os.environ, SCIPY_ARRAY_API="1", PYTHONPATH=str(root))
    run = subprocess.run([sys.executable, "-c", READ_BACK, NAME], input=json.dumps(payload), env=env,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    got = json.loads(run.stdout)
    assert Path(got["library"]).is_relative_to(root)  # the copy holding the section, not the installed one

    # the reference: the paper's rigid body with the induced drag F_B = -(sum Omega) diag(K) v_B
    # added by hand in the body frame
    x = torch.cat([torch.zeros(n, 3, dtype=torch.float64), vel, quat, w], dim=-1)
    v_body = so3.quat_rotate(so3.quat_conj(quat), vel)
    force = -om.sum(dim=-1, keepdim=True) * torch.tensor([K_XY, K_XY, K_Z], dtype=torch.float64) * v_body
    xdot = quad_dynamics(x, om, mass=vehicle.mass, inertia=vehicle.inertia, k_f=vehicle.k_f, k_m=vehicle.k_m,
                         arm=vehicle.arm, gravity=vehicle.gravity, force_body=force)
    torch.testing.assert_close(torch.tensor(got["vel_dot"], dtype=torch.float64), xdot[:, 3:6], rtol=1e-9, atol=1e-9)
    torch.testing.assert_close(torch.tensor(got["ang_vel_dot"], dtype=torch.float64), xdot[:, 10:13],
                               rtol=1e-9, atol=1e-6)
