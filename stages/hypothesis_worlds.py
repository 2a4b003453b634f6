"""hypothesis_worlds: the low-frequency roll/pitch torque's hypothesis tests (stages/hypotheses.py)
judged on simulated worlds of one effect each, whose truth is hidden from them: a study of the
tests, in the campaign's pipeline (campaign/dvc.yaml) beside discovery's."""

import logging
from pathlib import Path

from omegaconf import DictConfig

from nanosysid import campaign, hypothesis_worlds
from nanosysid.dataio import atomic_dir, atomic_file, json_text
from nanosysid.errors import ConfigError
from nanosysid.report.hypotheses import worlds_markdown
from nanosysid.sim import SimConfig
from stages.common import plain, run_stage, vehicle_of

log = logging.getLogger("nanosysid.hypothesis_worlds")


def _counts(hc: DictConfig) -> dict[str, int]:
    """The worlds per family (the settings' kinds are checked where the config is read)."""
    counts = {str(fam): int(n) for fam, n in (plain(hc.worlds) or {}).items()}
    unknown = sorted(set(counts) - set(hypothesis_worlds.FAMILIES))
    if unknown:
        raise ConfigError(f"hypotheses.worlds.{unknown[0]}: no such family; the families are "
                          f"{', '.join(hypothesis_worlds.FAMILIES)}")
    return {fam: n for fam, n in counts.items() if n}


def main(cfg: DictConfig) -> dict:
    """Draw ``hypotheses.worlds`` worlds per family from ``hypotheses.seed``, fly each one's
    training trajectories, test the hypotheses on them with the configured vehicle as the nominal
    model, and write ``<hypotheses.worlds_dir>/report.md`` and ``result.json``."""
    hc = cfg.hypotheses
    counts = _counts(hc)
    if not counts:
        raise ConfigError("hypotheses.worlds: no world in any family; the stage judges the tests on at least one")
    cutoff = float(hc.cutoff)
    window, order = int(cfg.discover.savgol_window), int(cfg.discover.savgol_order)
    setup_sim = campaign.short_flights_config(float(hc.duration), SimConfig.from_mapping(plain(cfg.sim.flight)))
    rows = hypothesis_worlds.check(hypothesis_worlds.draw(counts, int(hc.seed)), cfg=setup_sim,
                                   vehicle=vehicle_of(cfg), cutoff=cutoff, window=window, order=order, progress=True)
    worlds = {**hypothesis_worlds.summarize(rows), "rows": rows}
    with atomic_dir(Path(hc.worlds_dir)) as tmp:
        with atomic_file(tmp / "result.json") as f:
            f.write_text(json_text(worlds, sort_keys=True))
        with atomic_file(tmp / "report.md") as f:
            f.write_text(worlds_markdown(worlds, cutoff=cutoff))
    log.info("hypothesis worlds: %s", {fam: f"{r['met']}/{r['worlds']}" for fam, r in worlds["families"].items()})
    return worlds


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
