"""campaign: discovery over many hidden worlds (the worlds check), fanned out by the launcher;
its figures, one row per world, and the figures' plots."""

import logging
from pathlib import Path

from omegaconf import DictConfig

from nanosysid import campaign
from nanosysid.preprocess.sync import SyncConfig
from nanosysid.dataio import atomic_dir, atomic_file, json_text
from nanosysid.effects import LIBRARY
from nanosysid.errors import ConfigError
from nanosysid.launcher import Launcher
from nanosysid.report.campaign import summary_markdown, worlds_table
from nanosysid.sim import EFFECTS, SimConfig
from nanosysid.viz.campaign import confusion_figure, gap_figure, recall_figure
from stages.common import plain, run_stage, vehicle_of

log = logging.getLogger("nanosysid.campaign")
MIN_DURATION = 3.0  # s, a world's shortest flight the campaign's chain reads (the tests fly 10 s)


def main(cfg: DictConfig) -> dict:
    """Draw ``campaign.worlds`` worlds from ``campaign.seed``, run the worlds check on
    ``launcher`` with the configured vehicle and split, and write into ``campaign.out_dir`` (replaced atomically): ``summary.json``
    and ``summary.md``, ``worlds.parquet``, ``recall.png``, ``confusion.png``, ``gap.png``; then the families of
    ``campaign.families`` (:func:`nanosysid.campaign.families`), their rows in ``families.json`` and their counts
    in the summary."""
    c = cfg.campaign
    n, chunk = int(c.worlds), int(c.chunk)  # positive whole numbers: the config's rules check them
    if float(c.duration) < MIN_DURATION:
        raise ConfigError(f"campaign.duration = {c.duration} s; each world's flights need at least {MIN_DURATION:g} s "
                          "for the sync stage's clock fit and discovery's blocks")
    spec = Launcher.from_mapping(plain(cfg.launcher))
    draws = campaign.draw(n, int(c.seed), user_share=float(c.user_share), max_effects=int(c.max_effects))
    test = list(cfg.split.test)
    if len(test) != 1:
        raise ConfigError(f"split.test: {test}; the campaign scores one test trajectory per world")
    calibration = list(cfg.identify.calibration or [])
    setup = campaign.Setup(vehicle=vehicle_of(cfg), train=tuple(cfg.split.train), test=test[0],
                         calibration=calibration[0] if calibration else None,
                         sim=campaign.short_flights_config(float(c.duration), SimConfig.from_mapping(plain(cfg.sim.flight))),
                         sync=SyncConfig.from_mapping(plain(cfg.preprocess.sync)),
                         inertia_z_range=tuple(cfg.identify.inertia_z_range),
                         velocity=str(cfg.discover.velocity), flights_out=bool(cfg.discover.flights_out))
    counts = {k: int(v) for k, v in (plain(c.get("families")) or {}).items() if int(v)}
    unknown = set(counts) - set(campaign.FAMILIES)
    if unknown:
        raise ConfigError(f"campaign.families: {sorted(unknown)}; the families are {', '.join(campaign.FAMILIES)}")
    kin = campaign.families(counts, int(c.seed), start=n)
    # the drawn worlds and the families' in one fan-out: one set of workers, no wait between the
    # two (a world's row is the same in any task)
    every = campaign.check([*draws, *kin], launcher=spec, setup=setup, horizon=int(cfg.eval.horizon), chunk=chunk,
                           progress=True)
    rows, family_rows = every[:n], every[n:]
    relevant = float(c.relevant)
    summary = campaign.summarize(rows, relevant=relevant)
    summary["families"] = campaign.summarize_families(family_rows)
    effects = sorted(EFFECTS)
    table = worlds_table(rows, effects)
    described = [e for e in effects if campaign.DESCRIBED_BY[e]]
    out = Path(c.out_dir)
    with atomic_dir(out) as tmp:
        with atomic_file(tmp / "summary.json") as f:
            f.write_text(json_text(summary, sort_keys=True))
        with atomic_file(tmp / "summary.md") as f:
            f.write_text(summary_markdown(summary, relevant=relevant))
        with atomic_file(tmp / "worlds.parquet") as f:
            table.to_parquet(f, index=False)
        with atomic_file(tmp / "families.json") as f:
            f.write_text(json_text([{k: r.get(k) for k in ("world", "family", "effects", "named", "ambiguous",
                                                          "sources", "repeats", "history_dropped", "inertia_z", "diverged",
                                                          "error")}
                                    for r in family_rows], sort_keys=True))
        recall_figure(table, described, summary["strength_bins"], relevant, tmp / "recall.png")
        confusion_figure(table, effects, list(LIBRARY), tmp / "confusion.png")
        gap_figure(table, tmp / "gap.png")
    log.info("campaign: %d worlds on %s; precision %s, clean without a finding %s", n, spec.kind,
             summary["precision"], summary["clean_without_finding"])
    return summary


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
