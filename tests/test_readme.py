"""The README's generated results section: regenerated from the report, current with dvc.lock."""

import hashlib
import re
from pathlib import Path

import yaml

from nanosysid.report import readme

ROOT = Path(__file__).resolve().parents[1]


def test_readme_shows_the_results_the_lock_file_records():
    text = (ROOT / "README.md").read_text()
    assert text.count(readme.BEGIN) == 1 and text.count(readme.END) == 1
    part = text[text.index(readme.BEGIN):text.index(readme.END)]
    sources = dict(re.findall(r"(\S+) md5 ([0-9a-f]{32})", part))
    lock = yaml.safe_load((ROOT / "dvc.lock").read_text())
    outs = {o["path"]: o["md5"] for o in lock["stages"]["report"]["outs"]}
    assert sources == {p: outs[p] for p in ("reports/benchmark.md", "reports/figures/mae_horizon.png")}
    copy = re.search(r"\]\((docs/figures/[^)]+\.png)\)", part).group(1)
    assert hashlib.md5((ROOT / copy).read_bytes()).hexdigest() == outs["reports/figures/mae_horizon.png"]
    assert "| phys_res |" in part and "| oracle (physical limit) |" in part


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
