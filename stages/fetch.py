"""fetch: the rig's real flights, from rig.local or through DVC from the upstream repository at the
pinned commit, every file checked against the committed SHA-256 manifest."""

from omegaconf import DictConfig

from nanosysid.rig.fetch import fetch
from stages.common import run_stage


def main(cfg: DictConfig) -> None:
    c = cfg.rig
    fetch(c.manifest, c.paths.raw, local=c.local, repository=c.upstream.repository, commit=c.upstream.commit)


if __name__ == "__main__":
    raise SystemExit(run_stage(main, description=__doc__))
