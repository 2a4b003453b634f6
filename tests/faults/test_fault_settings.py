"""Settings of the wrong kind, out of range or not the data's are refused where the config is
read, in one line naming the setting and what it must be."""

from __future__ import annotations


import pytest

from nanosysid import config
from nanosysid.errors import ConfigError


CASES = [
    ("seed=abc", "seed must be a whole number >= 0"),
    ("seed=-1", "seed must be a whole number >= 0"),
    ("seed=1.5", "seed must be a whole number >= 0"),
    ("discover.folds=0", "discover.folds must be a whole number >= 2"),
    ("discover.folds=1", "discover.folds must be a whole number >= 2"),
    ("discover.folds=2.5", "discover.folds must be a whole number >= 2"),
    ("discover.block=0", "discover.block must be a positive number"),
    ("discover.block=-2", "discover.block must be a positive number"),
    ("discover.block=.inf", "discover.block must be a positive number"),
    ("models.physics.dt=0.02", "models.physics.dt = 0.02 s; the flights are sampled every 0.01 s"),
    ("models.physics_full.dt=0.005", "models.physics_full.dt = 0.005 s"),
    ("discover.oracle.dt=0.02", "discover.oracle.dt = 0.02 s"),
    ("preprocess.sync.rate=50", "preprocess.sync.rate = 50 Hz; the benchmark's flights are at 100 Hz"),
    ("preprocess.filter.rate=200", "preprocess.filter.rate = 200 Hz"),
    ("eval.horizon=0", "eval.horizon must be a positive whole number"),
    ("eval.horizon=ten", "eval.horizon must be a positive whole number"),
    ("models.lstm.train.optimizer.lr=-1", "models.lstm.train.optimizer.lr must be a positive number"),
    ("models.lstm.train.epochs=0", "models.lstm.train.epochs must be a positive whole number"),
    ("vehicle.mass=heavy", "vehicle.mass must be a positive number"),
    ("vehicle.k_f=0", "vehicle.k_f must be a positive number"),
    ("identify.iv_blocks=0", "identify.iv_blocks must be a positive whole number"),
    ("campaign.worlds=0", "campaign.worlds must be a positive whole number"),
    ("sim.runs.melon=-1", "sim.runs.melon must be a whole number >= 0"),
    ("preprocess.filter.position=60", "preprocess.filter.position = 60 Hz is at or above the Nyquist"),
    ("preprocess.sync.max_loss=-0.1", "preprocess.sync.max_loss must be a number >= 0"),
    ("preprocess.filter.max_hold=abc", "preprocess.filter.max_hold must be a whole number >= 0"),
    ("trainer.accelerator=tpu", "trainer.accelerator must be one of auto, cpu, gpu, cuda, mps, got 'tpu'"),
    ("trainer.devices=0", "trainer.devices must be a positive whole number or auto, got 0"),
    ("trainer.devices=two", "trainer.devices must be a positive whole number or auto"),
    ("models.lstm.train.optimizer._target_=torch.optim.Adamm", "models.lstm.train.optimizer._target_ must name a class of torch.optim"),
    ("models.lstm.train.optimizer._target_=os.remove", "must name a class of torch.optim (e.g. torch.optim.Adam), got 'os.remove'"),
    ("models.residual.train.scheduler._target_=torch.optim.Adam", "must name a class of torch.optim.lr_scheduler"),
    ("launcher.kind=cloud", "launcher.kind must be one of local, slurm, got 'cloud'"),
    ("preprocess.topics.odom.velocity_frame=sideways", "preprocess.topics.odom.velocity_frame must be one of world, body"),
    ("eval.table_horizons=[1,10,80]", "eval.table_horizons [1, 10, 80] go beyond the protocol's 50 steps"),
    ("eval.table_horizons=[0]", "eval.table_horizons must be a positive whole number"),
    ("+extra.flag=true", "adds the setting 'extra.flag', which params.yaml does not hold"),
    ("+seeds=1", "adds the setting 'seeds', which params.yaml does not hold"),
    ("eval.horizn=20", "cannot apply the overrides ['eval.horizn=20']: Could not override 'eval.horizn'"),
    ("out dir=x", "cannot read the overrides ['out dir=x']"),
    ("eval.table_horizons=[1", "quote a value with spaces or unusual letters"),
]

CLASS = "unchecked setting"


@pytest.mark.parametrize("override,words", CASES, ids=[c[0] for c in CASES])
def test_a_bad_setting_is_one_error_naming_it(params, override, words):
    with pytest.raises(ConfigError) as e:
        config.load_params([override], path=params)
    assert words in str(e.value), str(e.value)
    assert "\n" not in str(e.value)


def test_the_default_settings_pass(params):
    config.load_params([], path=params)


def test_launcher_slurm_without_a_cluster_is_one_line_saying_what_to_do(monkeypatch, tmp_path):
    from nanosysid.launcher import Launcher, slurm_executor

    monkeypatch.setattr("nanosysid.launcher.shutil.which", lambda name: None)
    with pytest.raises(ConfigError, match=r"launcher=slurm: no SLURM cluster here \(no sbatch on the PATH\); .* "
                                          "choose launcher=local"):
        slurm_executor(Launcher.from_mapping({"kind": "slurm", "folder": str(tmp_path)}))


def test_a_failed_cluster_job_is_one_line_naming_the_job_and_its_log(tmp_path):
    import operator

    from nanosysid.errors import JobError
    from nanosysid.launcher import Launcher, map_tasks

    spec = Launcher.from_mapping({"kind": "slurm", "cluster": "local", "folder": str(tmp_path / "jobs")})
    with pytest.raises(JobError, match=r"launcher=slurm: job \d+\S* failed \(ZeroDivisionError: division by zero\); "
                                       r"its log is in .*jobs"):
        map_tasks(operator.truediv, [(1, 0)], spec)


@pytest.mark.parametrize("override,words", [
    ("models.lstm.train.optimizer.weight_decay=-1", "Invalid weight_decay value: -1"),
    ("models.lstm.train.scheduler.factor=2", "Factor should be < 1.0"),
    ("models.lstm.train.optimizer.weight_decay=abc", "not supported between instances"),
])
def test_an_optimiser_the_class_refuses_is_one_error_before_training(params, override, words):
    from omegaconf import OmegaConf

    from nanosysid.models.training import optimiser_parts

    t = OmegaConf.to_container(config.load_params([override], path=params).models.lstm.train)
    with pytest.raises(ConfigError, match=r"models\.lstm\.train\.optimizer / scheduler: cannot build them") as e:
        optimiser_parts(t["optimizer"], t["scheduler"], "models.lstm.train")
    assert words in str(e.value)


@pytest.mark.parametrize("accelerator", ["cuda", "mps"])
def test_an_accelerator_this_machine_lacks_is_one_error_naming_the_setting(accelerator, tmp_path):
    import torch

    from nanosysid.models.training import train_model
    from nanosysid.synthetic import synthetic_flights

    if accelerator == "cuda" and torch.cuda.is_available() or accelerator == "mps" and torch.backends.mps.is_available():
        pytest.skip(f"this machine has {accelerator}")
    flights = synthetic_flights([f"square_20250101_run{k}" for k in (1, 2)], 60, seed=3)
    with pytest.raises(ConfigError, match=rf"train: trainer\.accelerator={accelerator}, trainer\.devices=1: .* on this "
                                          "machine; set trainer.accelerator=auto"):
        train_model({"name": "mlp", "options": {"hidden": [8]}}, flights, tmp_path / "m.pt", horizon=5, stride=5,
                    epochs=1, patience=1, batch_size=16, val_runs=[2], seed=0, progress=False, accelerator=accelerator)
    assert not (tmp_path / "m.pt").exists()


# ---- a world the controller cannot fly ---------------------------------------------------------

def free_fall(height: float, seconds: float):
    """A vehicle with its rotors off, let go at ``height`` m: z = height - g t^2 / 2."""
    import numpy as np

    from nanosysid.dataio import Flight

    t = np.round(np.arange(0.0, seconds, 0.01), 10)
    y = np.zeros((len(t), 13))
    y[:, 2] = height - 0.5 * 9.81 * t**2
    y[:, 5] = -9.81 * t
    y[:, 9] = 1.0
    return Flight("melon_20250601_run1", t, np.zeros((len(t), 4)), y, {})


def test_a_simulated_flight_below_the_floor_is_refused_at_the_instant_it_lands():
    """Let go at 1.5 m, the vehicle reaches the floor after sqrt(2 h / g) = 0.553 s: the first
    sample below it is t = 0.56 s."""
    from nanosysid.sim.envelope import check_flown

    with pytest.raises(ConfigError, match=r"melon_20250601_run1: at t = 0\.56 s of the simulated flight it is below "
                                          r"the floor \(z = -0\.04 m\): the controller lost the vehicle; "
                                          r"sim\.effects \(turbulence 50\) are beyond what it flies"):
        check_flown([free_fall(1.5, 1.0)], "sim.effects (turbulence 50)")
    check_flown([free_fall(1.5, 0.55)], "sim.effects")  # still above it


def test_a_world_that_overpowers_the_controller_is_refused_not_recorded():
    """Turbulence at 50 times its realistic size (a force of 250 mN std against the 441 mN
    weight of a 45 g vehicle) throws the vehicle down within seconds; at its realistic size it flies."""
    from nanosysid import sim
    from nanosysid.sim import SimConfig
    from nanosysid.sim.envelope import check_flown

    cfg = SimConfig.from_mapping({"preroll": 0.5, "compile": False, "trajectories": {
        "melon": {"duration": 4.0, "circle_time": 3.0, "return_time": 0.5, "ramp_time": 0.15}}})
    for strength, refused in ((50.0, True), (1.0, False)):
        flights = sim.simulate_flights({"melon": 1}, {"turbulence": strength}, 0, cfg=cfg, progress=False)
        if refused:
            with pytest.raises(ConfigError, match=r"melon_\d+_run1: at t = \d+\.\d\d s of the simulated flight it "
                                                  r"(is below the floor|has left the room)"):
                check_flown(flights, "sim.effects (turbulence 50)")
        else:
            check_flown(flights, "sim.effects")
