"""The generated sections of the README and its docs pages: regenerated from the reports, current
with dvc.lock; the README short enough to read in ten minutes, its commands each run by a test."""

import hashlib
import json
import re
from pathlib import Path

import docpages
import yaml

from nanosysid.report import readme

ROOT = Path(__file__).resolve().parents[1]


def stamped(begin, end, stages):
    """A generated section (of the README or a docs page), the sources its stamp names, and the
    outputs of ``stages`` as the committed locks (``dvc.lock``, ``rig/dvc.lock``) record them."""
    text = docpages.page_of(begin).read_text()
    assert text.count(begin) == 1 and text.count(end) == 1
    part = text[text.index(begin):text.index(end)]
    locked = {name: st for f in ("dvc.lock", "rig/dvc.lock")
              for name, st in yaml.safe_load((ROOT / f).read_text())["stages"].items()}
    outs = {o["path"]: o["md5"] for st in stages for o in locked[st]["outs"]}
    return part, dict(re.findall(r"(\S+) md5 ([0-9a-f]{32})", part)), outs


def figure_copy(begin: str, part: str) -> Path:
    """The copy of a figure a generated section shows, from its link relative to the page."""
    link = re.search(r"\]\(((?:docs/)?figures/[^)]+\.png)\)", part).group(1)
    return docpages.page_of(begin).parent / link


def test_the_generated_sections_are_on_the_pages_the_generator_writes():
    for which, begin in (("results", readme.BEGIN), ("rig", readme.RIG_BEGIN), ("campaign", readme.CAMPAIGN_BEGIN),
                         ("physics", readme.PHYSICS_BEGIN), ("world", readme.WORLD_BEGIN), ("bench", readme.BENCH_BEGIN),
                         ("reliability", readme.FAULTS_BEGIN), ("headline", readme.HEADLINE_BEGIN),
                         ("start", readme.START_BEGIN)):
        assert docpages.page_of(begin) == ROOT / readme.PAGES[which], which


def test_the_readme_reads_in_ten_minutes():
    """At most 3,000 words (whitespace-separated, tables and code included); depth is in docs/."""
    words = len((ROOT / "README.md").read_text().split())
    assert words <= 3000, words


def test_every_link_between_the_pages_lands_on_a_file():
    """Links into reports/ name the pipeline's outputs, there after `make repro` (DVC tracks them)."""
    for page in docpages.pages():
        for target in re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", page.read_text()):
            path = (page.parent / target).resolve()
            if (ROOT / "reports") in path.parents:
                continue
            assert path.exists(), (page.name, target)


def test_readme_headline_is_the_rig_comparison_the_lock_file_records(monkeypatch):
    part, sources, outs = stamped(readme.HEADLINE_BEGIN, readme.HEADLINE_END, ["rig_compare"])
    assert sources == {"reports/rig/paper.md": outs["reports/rig/paper.md"]}
    assert "| phys_res |" in part and "| paper |" in part


def test_readme_start_time_is_the_repro_record(monkeypatch):
    monkeypatch.chdir(ROOT)
    text = (ROOT / "README.md").read_text()
    part = text[text.index(readme.START_BEGIN):text.index(readme.START_END) + len(readme.START_END)]
    assert part == readme.start_section(Path("reports/repro.json"), Path("reports/campaign-repro.json"),
                                        Path("reports/repro-sim.json"), Path("reports/bench.json"))


def test_the_start_section_gives_the_simulated_pipelines_own_time_and_refuses_a_record_of_both(tmp_path):
    import pytest

    machine = {"cpu": "X", "cores": 2, "threads": 2, "torch": "t", "python": "p"}
    both = {"stages": {"simulate@sim": 60.0, "rig/dvc.yaml:rig_fetch": 3.0}, "skipped": [], "total_s": 1500.0,
            "machine": machine}
    alone = {**both, "stages": {"simulate@sim": 60.0}, "total_s": 630.0}
    for name, rec in (("both.json", both), ("alone.json", alone)):
        (tmp_path / name).write_text(json.dumps(rec))
    text = readme.start_section(tmp_path / "both.json", None, tmp_path / "alone.json")
    assert "both data sources in 1500 s (25 min)" in text and "pipeline alone) it took 630 s (10 min;" in text
    without = readme.start_section(tmp_path / "both.json", None, tmp_path / "absent.json")
    assert "(the simulated" not in without
    with pytest.raises(ValueError, match="rig"):
        readme.start_section(tmp_path / "both.json", None, tmp_path / "both.json")
    # `make bench`'s fresh-clone time of `make test`, its environment build in it: 579.1 s is 9.65 min
    suite = {"fresh_clone_s": 579.1, "environment_build_s": 28.2, "make_test_s": 550.9}
    (tmp_path / "bench.json").write_text(json.dumps({"machine": machine, "benchmarks": {"test_suite": {"figures": suite}}}))
    text = readme.start_section(tmp_path / "both.json", None, None, tmp_path / "bench.json")
    assert text.count("`make test` took 579.1 s (10 min) in a fresh clone, 28.2 s of it building the environment") == 1
    (tmp_path / "bench.json").write_text(json.dumps({"machine": machine, "benchmarks": {}}))
    assert "`make test`" not in readme.start_section(tmp_path / "both.json", None, None, tmp_path / "bench.json")
    # make readme keeps the last record by the run it is of: a run whose rig stages were all cached
    # is of both sources still
    cached = {**alone, "skipped": ["rig/dvc.yaml:rig_fetch"]}
    for rec, kept in ((both, "repro.json"), (alone, "repro-sim.json"), (cached, "repro.json")):
        last = tmp_path / "last.json"
        last.write_text(json.dumps(rec))
        to = readme.keep_repro_record(last, tmp_path / "repro.json", tmp_path / "repro-sim.json")
        assert to.name == kept and json.loads(to.read_text()) == rec


def test_readme_shows_the_results_the_lock_file_records():
    part, sources, outs = stamped(readme.BEGIN, readme.END, ["report"])
    assert sources == {p: outs[p] for p in ("reports/benchmark.md", "reports/figures/mae_horizon.png")}
    copy = figure_copy(readme.BEGIN, part)
    assert hashlib.md5(copy.read_bytes()).hexdigest() == outs["reports/figures/mae_horizon.png"]
    assert "| phys_res |" in part and "| oracle (physical limit) |" in part


def test_readme_physics_section_is_the_compare_and_quality_reports_the_lock_file_records():
    part, sources, outs = stamped(readme.PHYSICS_BEGIN, readme.PHYSICS_END, ["compare@sim", "quality@sim"])
    assert sources == {p: outs[p] for p in ("reports/sim/stats.md", "reports/data/quality.md")}
    assert "| k_M, the paper's method |" in part and "| phys_res / physics, ours |" in part
    assert "| melon_20250601_run1 |" in part


def test_physics_section_takes_the_sections_it_names(tmp_path):
    stats = tmp_path / "stats.md"
    stats.write_text("# The dataset\n\n## Identification against nature\n\nIDENT\n\n## Other\n\nNO\n\n"
                     "## The pattern of the results: SimErr over the physics model's\n\nPATTERN\n\n## Verdict\n\nV\n")
    quality = tmp_path / "quality.md"
    quality.write_text("# Processed data against the simulator's truth\n\nQUALITY\n\n## The physics baseline\n\nNO\n")
    md = tmp_path / "README.md"
    md.write_text(f"a\n{readme.PHYSICS_BEGIN}\nold\n{readme.PHYSICS_END}\nb\n")
    assert readme.update_physics(md, stats, quality)
    text = md.read_text()
    assert all(w in text for w in ("IDENT", "PATTERN", "QUALITY")) and "NO" not in text and "old" not in text
    assert text.startswith("a\n") and text.endswith("\nb\n")


def test_update_replaces_only_the_section(tmp_path):
    report = tmp_path / "reports" / "benchmark.md"
    report.parent.mkdir()
    report.write_text("# Benchmark report\n\n## Multi-step prediction on the test flights\n\n| a | b |\n|---|---|\n"
                      "| x | 1.0 |\n\n## Cost of one step\n\n| c |\n")
    fig = tmp_path / "fig.png"
    fig.write_bytes(b"\x89PNG fake")
    md = tmp_path / "README.md"
    md.write_text(f"# title\n\nbefore\n\n{readme.BEGIN}\nold text\n{readme.END}\n\nafter\n")
    assert readme.update(md, report, fig, tmp_path / "docs" / "fig.png")
    text = md.read_text()
    assert text.startswith("# title\n\nbefore\n\n") and text.endswith("\n\nafter\n")
    assert "old text" not in text and "| x | 1.0 |" in text and "](docs/fig.png)" in text and "Cost" not in text
    assert (tmp_path / "docs" / "fig.png").read_bytes() == fig.read_bytes()
    assert not readme.update(md, report, fig, tmp_path / "docs" / "fig.png")  # current: unchanged


def readme_table():
    text = docpages.page_of(readme.BEGIN).read_text()
    part = text[text.index(readme.BEGIN):text.index(readme.END)]
    lines = [line for line in part.splitlines() if line.startswith("|")]
    head = [c.strip() for c in lines[0].strip("|").split("|")]
    rows = {}
    for line in lines[2:]:
        cells = [c.strip() for c in line.strip("|").split("|")]
        rows[cells[0]] = cells[1:]
    return part, lines, head, rows


def test_readme_results_table_reads_right():
    """The table's own text: one number per cell, the bold one the least of its column among
    the models (the oracle is a limit, not a model), and the physics model, which holds the
    angular velocity constant, scoring the naive model's angular-velocity error."""
    _, _, head, rows = readme_table()
    assert head[0] == "Model" and len(head) == 17
    assert {"naive", "physics", "physics_full", "oracle (physical limit)", "residual", "phys_res", "lstm"} <= set(rows)
    values = {m: [float(c.strip("*")) for c in cells] for m, cells in rows.items()}
    assert all(len(v) == 16 for v in values.values())
    models = [m for m in rows if not m.startswith("oracle")]
    for j in range(16):
        best = min(values[m][j] for m in models)
        bold = [m for m in rows if rows[m][j].startswith("**")]
        assert bold and all(values[m][j] == best for m in bold), (head[j + 1], bold)
    assert rows["physics"][12:] == rows["naive"][12:]
    # the sum over 50 horizons is at least the error at the 50th
    for m, v in values.items():
        for q in range(4):
            assert v[4 * q + 3] >= v[4 * q + 2], m


def test_readme_table_is_the_report_table_when_the_report_is_here():
    """Where the report stage's output is present and is the one the stamp names, the README
    shows its table verbatim."""
    import pytest

    report = ROOT / "reports" / "benchmark.md"
    part, lines, _, _ = readme_table()
    stamped = dict(re.findall(r"(\S+) md5 ([0-9a-f]{32})", part))
    if not report.exists() or hashlib.md5(report.read_bytes()).hexdigest() != stamped["reports/benchmark.md"]:
        pytest.skip("reports/benchmark.md is not the stamped report (run `make repro`)")
    text = report.read_text()
    start = text.index("## Multi-step prediction")
    table = [line for line in text[start:text.index("\n## ", start + 1)].splitlines() if line.startswith("|")]
    assert lines == table


def test_readme_run_times_are_the_bench_record(monkeypatch):
    """Every time the README and its pages state is in the run-times sections, generated from the
    committed records of `make bench` and `make repro`; no time is typed elsewhere in the prose."""
    monkeypatch.chdir(ROOT)
    text = docpages.page_of(readme.BENCH_BEGIN).read_text()
    part = text[text.index(readme.BENCH_BEGIN):text.index(readme.BENCH_END) + len(readme.BENCH_END)]
    assert part == readme.bench_section(Path("reports/bench.json"), Path("reports/repro.json"))
    everything = docpages.text()
    start = everything[everything.index(readme.START_BEGIN):everything.index(readme.START_END)]
    rest = everything.replace(part, "").replace(start, "")
    assert not re.findall(r"about \d+(\.\d+)? ?(s|min|minutes|seconds)\b", rest)


def test_readme_reliability_section_is_the_fault_matrix_record(monkeypatch):
    # the record is rewritten by every full run of tests/faults (collected before this file)
    from nanosysid.report.readme import FAULTS_BEGIN, FAULTS_END, faults_section

    monkeypatch.chdir(ROOT)
    text = docpages.page_of(FAULTS_BEGIN).read_text()
    part = text[text.index(FAULTS_BEGIN):text.index(FAULTS_END) + len(FAULTS_END)]
    record = json.loads((ROOT / "tests" / "faults" / "record.json").read_text())
    assert part == faults_section(Path("tests/faults/record.json")), \
        "run `python -m nanosysid.report.readme --sections reliability`"
    rows = [line.split("|")[2:4] for line in part.splitlines() if line.startswith("| ") and "class of fault" not in line]
    assert sum(int(c) for c, _ in rows[:-1]) == record["cases"] == int(rows[-1][0])


def test_readme_world_table_is_the_effects_records():
    text = docpages.page_of(readme.WORLD_BEGIN).read_text()
    part = text[text.index(readme.WORLD_BEGIN):text.index(readme.WORLD_END) + len(readme.WORLD_END)]
    assert part == readme.world_section(), "run `python -m nanosysid.report.readme --sections world`"


def test_repro_times_each_stage_from_dvcs_own_lines():
    from nanosysid.report.runtimes import stage_times

    lines = ["Running stage 'simulate':\n", "> python -m stages.simulate\n", "Updating lock file 'dvc.lock'\n",
             "Stage 'extract' didn't change, skipping\n", "Running stage 'sync':\n", "> python -m stages.sync\n",
             "Running stage 'train@lstm':\n", "Updating lock file 'dvc.lock'\n"]
    ticks = iter([0.0, 1.0, 4.0, 11.5, 12.0, 12.5, 13.0, 20.0, 60.0, 61.0])  # the start, one tick per line, the end
    record = stage_times(lines, clock=lambda: next(ticks))
    # simulate from its line (1.0) to the lock update (11.5); sync until the next stage starts
    assert record == {"stages": {"simulate": 10.5, "sync": 7.5, "train@lstm": 40.0}, "skipped": ["extract"],
                      "total_s": 61.0}


def test_readme_real_flights_section_is_the_rig_reports_the_lock_file_records():
    part, sources, outs = stamped(readme.RIG_BEGIN, readme.RIG_END, ["rig_compare", "rig_report"])
    assert sources == {p: outs[p] for p in ("reports/rig/paper.md", "reports/rig/figures/mae_horizon.png")}
    copy = figure_copy(readme.RIG_BEGIN, part)
    assert hashlib.md5(copy.read_bytes()).hexdigest() == outs["reports/rig/figures/mae_horizon.png"]
    assert "| phys_res |" in part and "| paper |" in part and "| k_F [N s²/rad²] |" in part


def test_the_real_flights_section_is_left_alone_where_the_rig_pipeline_did_not_run(tmp_path):
    md = tmp_path / "README.md"
    md.write_text(f"a\n{readme.RIG_BEGIN}\nold\n{readme.RIG_END}\nb\n")
    assert readme.update_rig(md, tmp_path / "paper.md", tmp_path / "fig.png", tmp_path / "copy.png") is None
    assert "old" in md.read_text()
    paper = tmp_path / "paper.md"
    paper.write_text("# Real\n\n## The results beside the paper's table\n\nRESULTS\n\n## The pattern of the results: SimErr "
                     "over the physics model's\n\nPATTERN\n\n## Identification beside the paper's"
                     "\n\nIDENT\n\n## The motor alignment beside the authors'\n\nLAG\n\n## Trajectory statistics\n\nNO\n")
    (tmp_path / "fig.png").write_bytes(b"png")
    assert readme.update_rig(md, paper, tmp_path / "fig.png", tmp_path / "docs" / "copy.png")
    text = md.read_text()
    assert all(w in text for w in ("RESULTS", "IDENT", "LAG", "](docs/copy.png)")) and "NO" not in text and "old" not in text
    # the pattern on the real flights under a title of its own: the physics section has the world's
    assert "#### The pattern on the real flights: SimErr over the physics model's\n\nPATTERN" in text


def test_the_readmes_ablation_names_the_stages_dvc_reruns():
    # tests/test_dvc.py runs the experiment and checks these very stages against DVC's log
    from test_dvc import EXPERIMENTS

    change, reruns = EXPERIMENTS["substeps"]
    line = next(x for x in docpages.text().splitlines() if x.startswith(f"dvc exp run -S {change}"))
    claimed = line.split("reruns", 1)[1].strip().split(", ")
    assert claimed == list(reruns), (claimed, reruns)


def readme_commands(prefix: str) -> list[str]:
    """The shell command lines (in ```bash blocks) of the README and its pages that start with
    ``prefix``, comments cut."""
    text = docpages.text()
    lines = [line for block in re.findall(r"```bash\n(.*?)```", text, flags=re.S) for line in block.splitlines()]
    return [line.split("  #")[0].strip() for line in lines if line.startswith(prefix)]


def test_the_readmes_minio_remote_commands_configure_dvc(tmp_path):
    import shlex
    import subprocess

    from dvcenv import dvc_env

    add, = readme_commands("dvc remote add")
    modify, = readme_commands("dvc remote modify")
    # endpointurl is an S3 option: the remote is the comment's s3:// alternative
    s3 = re.search(r"or: (s3://\S+)", next(x for x in docpages.text().splitlines()
                                           if x.startswith("dvc remote add"))).group(1)
    env = dvc_env()
    for cmd in (["git", "init", "-q"], ["dvc", "init", "-q"], shlex.split(add)[:-1] + [s3], shlex.split(modify)):
        r = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True)
        assert r.returncode == 0, (cmd, r.stderr)
    config = (tmp_path / ".dvc" / "config").read_text()
    assert f"url = {s3}" in config and "endpointurl = http://minio:9000" in config and "remote = store" in config


def test_the_readmes_slurm_experiment_composes_and_says_what_this_machine_lacks(monkeypatch):
    from nanosysid import config, launcher
    from nanosysid.errors import ConfigError

    line, = [x for x in readme_commands("dvc exp run campaign/dvc.yaml -S launcher=slurm")]
    overrides = re.findall(r"-S (\S+)", line)
    assert overrides == ["launcher=slurm", "launcher.partition=cpu", "campaign.worlds=500"]
    cfg = yaml.safe_load(config.compose_text(overrides))
    assert cfg["launcher"]["kind"] == "slurm" and cfg["launcher"]["partition"] == "cpu"
    assert cfg["campaign"]["worlds"] == 500
    spec = launcher.Launcher(**{k: v for k, v in cfg["launcher"].items() if k in launcher.Launcher.__dataclass_fields__})
    monkeypatch.setattr(launcher.shutil, "which", lambda name: None)  # no SLURM here: one clear line
    try:
        launcher.slurm_executor(spec)
    except ConfigError as e:
        assert "no SLURM cluster here (no sbatch on the PATH)" in str(e)
    else:
        raise AssertionError("a slurm launcher without sbatch must be refused")


def test_the_readmes_rig_local_compose_writes_the_folder_into_the_rigs_params(tmp_path):
    import shlex
    import subprocess
    import sys

    line, = readme_commands("python -m nanosysid.config compose rig.local=")
    import shutil

    shutil.copytree(ROOT / "conf", tmp_path / "conf")
    r = subprocess.run([sys.executable, *shlex.split(line)[1:]], cwd=tmp_path, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    folder = line.split("rig.local=")[1]
    assert yaml.safe_load((tmp_path / "params-rig.yaml").read_text())["rig"]["local"] == folder
    assert "params.yaml" in r.stdout and (tmp_path / "params.yaml").is_file()


def test_the_readmes_recording_command_names_a_recording_visualize_writes_and_the_viewer_it_installs():
    import subprocess

    line, = readme_commands(".venv/bin/rerun ")
    viewer, recording = line.split()
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    assert Path(recording).parent == Path(params["visualize"]["out_dir"])
    assert Path(recording).stem == f"{params['split']['test'][0]}_{params['sim']['date']}_run1"
    assert params["sim"]["runs"][params["split"]["test"][0]] >= 1
    # the viewer the environment installs (opening a window is left to the reader)
    r = subprocess.run([str(ROOT / viewer), "--version"], capture_output=True, text=True)
    assert r.returncode == 0 and "rerun" in r.stdout.lower(), (r.stdout, r.stderr)


def test_the_readmes_bench_command_names_benchmarks_that_exist():
    import importlib.util
    import subprocess
    import sys

    names = re.findall(r'NAMES="?([a-z_ ]+)"?', docpages.text())
    assert names
    bench = importlib.util.spec_from_file_location("bench_run", ROOT / "benchmarks" / "run.py")
    module = importlib.util.module_from_spec(bench)
    bench.loader.exec_module(module)
    for name in {n for ns in names for n in ns.split()}:
        assert name in module.BENCHMARKS, name
    for name in module.BENCHMARKS:
        source = (ROOT / "benchmarks" / f"{name}.py").read_text()
        assert "\ndef main(" in source and source.startswith('"""'), name
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "run.py"), "nosuch"], capture_output=True, text=True)
    assert r.returncode == 2 and "unknown benchmark nosuch: choose from" in r.stderr


def test_bench_gives_each_time_against_the_previous_record_and_the_section_shows_it(tmp_path):
    import importlib.util

    bench = importlib.util.spec_from_file_location("bench_run", ROOT / "benchmarks" / "run.py")
    module = importlib.util.module_from_spec(bench)
    bench.loader.exec_module(module)
    # 3.0 s before, 1.5 s now: half the time; counts, flags and in-run ratios are no times
    previous = {"fit_s": 3.0, "loop_s": 0.0, "windows": 100, "same": True, "fit_over_loop": 4.0}
    now = {"fit_s": 1.5, "loop_s": 2.0, "windows": 200, "same": True, "fit_over_loop": 2.0, "new_s": 1.0}
    assert module.against_previous(previous, now) == {"fit_s": 0.5}
    machine = {"cpu": "X", "cores": 2, "threads": 2, "torch": "t", "python": "p"}
    record = {"machine": machine, "benchmarks": {
        "a": {"about": "A.", "figures": now, "against_previous": {"fit_s": 0.5}},
        "b": {"about": "B.", "figures": {"run_s": 1.0}}}}
    (tmp_path / "bench.json").write_text(json.dumps(record))
    section = readme.bench_section(tmp_path / "bench.json")
    rows = [line for line in section.splitlines() if line.startswith("| `")]
    assert rows[0].endswith("| fit: 0.5x |") and rows[1].endswith("| – |"), rows


# every shell command of the README, by the start of its line, and where it is run as written
# (file::test); a command added to the README without a runner fails the census below
RUN_BY = {
    "make repro": "tests/test_repro.py::test_make_repro_and_make_test_write_no_tracked_file_and_install_only_what_is_missing",
    "make test": ".ci/run",
    "make quick": "tests/test_repro.py::test_make_quick_composes_the_profile_and_runs_both_pipelines_without_the_rigs"
                  "_stages",
    "make bench": "tests/test_readme.py::test_the_readmes_bench_command_names_benchmarks_that_exist",
    ".venv/bin/rerun ": "tests/test_readme.py::test_the_readmes_recording_command_names_a_recording_visualize_writes"
                        "_and_the_viewer_it_installs",
    "dvc exp run -S data=csv": "tests/test_dvc.py::test_a_users_own_flights_run_through_one_experiment_without_the"
                               "_simulators_stages",
    "dvc exp run -S models.physics.substeps=4": "tests/test_dvc.py::test_queued_experiments_rerun_only_what_changed"
                                                "_and_share_the_run_cache",
    # (what it reruns, by `dvc status`: the tests have no real flights to run it on)
    "dvc exp run rig/dvc.yaml -S params-rig.yaml:": "tests/test_dependencies.py::test_an_ablation_reruns_stages_of_the"
                                                   "_source_whose_settings_it_changes_only",
    "dvc exp show": "tests/test_dvc.py::test_queued_experiments_rerun_only_what_changed_and_share_the_run_cache",
    "dvc exp run --queue": "tests/test_dvc.py::test_queued_experiments_rerun_only_what_changed_and_share_the_run_cache",
    "dvc queue start": "tests/test_dvc.py::test_queued_experiments_rerun_only_what_changed_and_share_the_run_cache",
    "python -m stages.campaign": "tests/test_launcher.py::test_campaign_gives_the_same_bytes_with_one_or_two_workers",
    "dvc exp run campaign/dvc.yaml -S launcher=slurm": "tests/test_readme.py::test_the_readmes_slurm_experiment_"
                                                       "composes_and_says_what_this_machine_lacks",
    "make campaign": "tests/test_repro.py::test_each_pipeline_file_runs_apart_and_the_run_names_what_the_other_would_rerun",
    "dvc remote add": "tests/test_readme.py::test_the_readmes_minio_remote_commands_configure_dvc",
    "dvc remote modify": "tests/test_readme.py::test_the_readmes_minio_remote_commands_configure_dvc",
    "dvc push --run-cache": "tests/test_dvc.py::test_outputs_and_run_cache_round_trip_through_a_remote",
    "dvc pull --run-cache": "tests/test_dvc.py::test_outputs_and_run_cache_round_trip_through_a_remote",
    "python -m nanosysid.config compose rig.local=": "tests/test_readme.py::test_the_readmes_rig_local_compose_writes"
                                                    "_the_folder_into_the_rigs_params",
}


def test_every_readme_command_has_a_test_that_runs_it():
    text = docpages.text(readme_only=True)
    lines = [line.split("  #")[0].strip() for block in re.findall(r"```bash\n(.*?)```", text, flags=re.S)
             for line in block.splitlines() if line.strip() and not line.startswith("#")]
    unrun = [line for line in lines if not any(line.startswith(k) for k in RUN_BY)]
    assert not unrun, f"README commands no test runs: {unrun}"
    for key, where in RUN_BY.items():
        assert any(line.startswith(key) for line in lines), f"{key!r}: no longer in the README"
        file, _, test = where.partition("::")
        source = (ROOT / file).read_text()
        assert not test or f"def {test}(" in source, where


def test_the_window_tracks_lines_are_its_reports_table_and_last_verdict(tmp_path):
    md = tmp_path / "report.md"
    md.write_text("# The initialization-window track (W = 50 samples)\n\nIntro.\n\n| SimErr on the test flights, W = 50 "
                  "| p |\n|---|---|\n| `physics` | 1 |\n\nText.\n\n| flights | x |\n|---|---|\n| a | 2 |\n\n"
                  "**Old**: no.\n\n**What stops it**: this.\n")
    lines = readme.window_lines(md)
    assert lines[0] == "#### The initialization-window track (W = 50 samples)"
    assert "| `physics` | 1 |" in lines and "| a | 2 |" not in lines
    assert "**What stops it**: this." in lines and "**Old**: no." not in lines


def test_the_hypotheses_lines_are_the_reports_verdicts_and_checks(tmp_path):
    rig, sim = tmp_path / "rig.md", tmp_path / "sim.md"
    rig.write_text("# Title\n\nIntro.\n\n**Verdict.** `drag_moment` explains 86 %.\n\n| hypothesis | x |\n|---|---|\n"
                   "| `cg_offset` | 1 |\n\n## The hover check\n\nResidual torque in hover, mean: 1.\n\n"
                   "Mean over flights: r_x 2.\n")
    sim.write_text("# Title\n\n**Verdict.** The air.\n\n| hypothesis | x |\n|---|---|\n| a | 1 |\n")
    lines = readme.hypotheses_lines(rig, sim)
    assert "**Verdict.** `drag_moment` explains 86 %." in lines
    assert "Residual torque in hover, mean: 1." in lines and "Mean over flights: r_x 2." in lines
    assert "| `cg_offset` | 1 |" not in lines and "| a | 1 |" not in lines
    assert "On the default simulated world's flights: The air." in lines
    # without the simulated pipeline's report, the rig's lines alone
    alone = readme.hypotheses_lines(rig, tmp_path / "absent.md")
    assert not any("simulated world" in line for line in alone) and alone == lines[:-2]


def test_readme_campaign_section_is_the_summary_the_campaigns_lock_records(monkeypatch):
    monkeypatch.chdir(ROOT)  # the lock names its outputs relative to the project's root
    text = docpages.page_of(readme.CAMPAIGN_BEGIN).read_text()
    part = text[text.index(readme.CAMPAIGN_BEGIN):text.index(readme.CAMPAIGN_END) + len(readme.CAMPAIGN_END)]
    sources = dict(re.findall(r"(\S+) md5 ([0-9a-f]{32}(?:\.dir)?)", part))
    lock = yaml.safe_load((ROOT / "campaign" / "dvc.lock").read_text())
    (out,) = lock["stages"]["campaign@sim"]["outs"]
    assert sources["reports/campaign"] == out["md5"]
    summary = Path("reports/campaign/summary.md")
    if summary.exists() and hashlib.md5(summary.read_bytes()).hexdigest() == sources[summary.as_posix()]:
        record, worlds = Path("reports/campaign-repro.json"), Path("reports/hypothesis-worlds/report.md")
        page = docpages.page_of(readme.CAMPAIGN_BEGIN)  # its links are written relative to the page
        assert part == readme._relink(page, readme.campaign_section(summary, Path("campaign/dvc.lock"), record,
                                                                     worlds_md=worlds))
    # the hypothesis tests' worlds table, stamped with what the lock records for its folder
    (worlds_out,) = lock["stages"]["hypothesis_worlds@sim"]["outs"]
    assert sources["reports/hypothesis-worlds"] == worlds_out["md5"]


def test_the_campaign_section_copies_its_reports_counts_and_refuses_one_its_lock_does_not_record(tmp_path):
    import pytest

    out = tmp_path / "reports" / "campaign"
    out.mkdir(parents=True)
    (out / "summary.md").write_text(
        "# Discovery over hidden worlds\n\n10 worlds, 1 where it diverged.\n\n| recall | x |\n|---|---|\n| a | 1 |\n\n"
        "- named verdicts: 8, right 88 %\n- clean worlds: 4\n\n## Identification over the worlds\n\n- k_F: ok\n\n"
        "## A function of the state, of the input history, or of time\n\nWorlds of one kind.\n\n| family | worlds |\n"
        "|---|---|\n| thrust_lag | 5 |\n\nAfter.\n")
    lock = tmp_path / "dvc.lock"
    lock.write_text(yaml.safe_dump({"schema": "2.0", "stages": {"campaign@sim": {
        "outs": [{"path": out.as_posix(), "md5": "ab" + "0" * 30 + ".dir"}]}}}))
    cache = tmp_path / "cache"
    text = readme.campaign_section(out / "summary.md", lock, None, cache)  # no listing in the cache: taken
    body = text.splitlines()[3:-3]
    assert body == ["10 worlds, 1 where it diverged.", "", "- named verdicts: 8, right 88 %", "- clean worlds: 4", "",
                    "| family | worlds |", "|---|---|", "| thrust_lag | 5 |", ""], body
    assert "ab" + "0" * 30 + ".dir" in text and "k_F" not in text and "| a | 1 |" not in text
    listing = cache / "files" / "md5" / "ab" / ("0" * 30 + ".dir")
    listing.parent.mkdir(parents=True)
    listing.write_text(json.dumps([{"relpath": "summary.md", "md5": "f" * 32}]))
    with pytest.raises(ValueError, match="is not the one .* records"):
        readme.campaign_section(out / "summary.md", lock, None, cache)


def test_the_campaign_section_ends_with_the_hypothesis_tests_worlds_table_its_lock_records(tmp_path):
    import pytest

    out, worlds = tmp_path / "reports" / "campaign", tmp_path / "reports" / "hypothesis-worlds"
    out.mkdir(parents=True)
    worlds.mkdir()
    (out / "summary.md").write_text("# Discovery over hidden worlds\n\n- named verdicts: 8\n")
    (worlds / "report.md").write_text("# Worlds\n\nIntro.\n\n| world family | worlds | met |\n|---|---|---|\n"
                                      "| com_offset | 20 | 19/20 |\n\nAfter.\n")
    lock = tmp_path / "dvc.lock"
    lock.write_text(yaml.safe_dump({"schema": "2.0", "stages": {
        "campaign@sim": {"outs": [{"path": out.as_posix(), "md5": "ab" + "0" * 30 + ".dir"}]},
        "hypothesis_worlds@sim": {"outs": [{"path": worlds.as_posix(), "md5": "cd" + "1" * 30 + ".dir"}]}}}))
    text = readme.campaign_section(out / "summary.md", lock, None, tmp_path / "cache", worlds_md=worlds / "report.md")
    lines = text.splitlines()
    table = lines.index("| world family | worlds | met |")
    assert lines[table:table + 4] == ["| world family | worlds | met |", "|---|---|---|", "| com_offset | 20 | 19/20 |", ""]
    assert f"{worlds.as_posix()} md5 cd{'1' * 30}.dir" in text and "After." not in text and "Intro." not in text
    assert table > lines.index("- named verdicts: 8") and lines[-1] == readme.CAMPAIGN_END
    # a report other than the one DVC's cache lists for the recorded folder is refused
    listing = tmp_path / "cache" / "files" / "md5" / "cd" / ("1" * 30 + ".dir")
    listing.parent.mkdir(parents=True)
    listing.write_text(json.dumps([{"relpath": "report.md", "md5": "f" * 32}]))
    with pytest.raises(ValueError, match="is not the one .* records"):
        readme.campaign_section(out / "summary.md", lock, None, tmp_path / "cache", worlds_md=worlds / "report.md")
    # without the worlds report (make campaign's stage not run here), the campaign's counts alone
    alone = readme.campaign_section(out / "summary.md", lock, None, tmp_path / "cache", worlds_md=worlds / "absent.md")
    assert "world family" not in alone and "hypothesis-worlds" not in alone
