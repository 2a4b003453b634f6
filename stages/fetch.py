"""fetch: the rig's real flights, from rig.local or the upstream repository at the pinned commit,
every file checked against the committed SHA-256 manifest."""

from omegaconf import DictConfig

from nanosysid.rig.fetch import fetch
from stages.common import run_stage


def main(cfg: DictConfig) -> None:
    c = cfg.rig
    fetch(c.manifest, c.paths.raw, local=c.local, url=c.upstream.url, repository=c.upstream.repository,
          commit=c.upstream.commit, timeout=float(c.timeout))


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
