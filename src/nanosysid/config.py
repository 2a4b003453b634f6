"""Configuration: ``conf/`` (Hydra) is the source of truth, ``params.yaml`` its composition.

DVC composes ``params.yaml`` from ``conf/`` on ``dvc exp run`` only; :func:`compose` does the
same composition with DVC's own function (same bytes), for ``make repro`` and the tests.
Stages read ``params.yaml`` through :func:`load_params`, with Hydra-style overrides on top.

Command line::

    python -m nanosysid.config compose [override ...]   # write params.yaml
    python -m nanosysid.config check                    # exit 1 if params.yaml is stale
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
from typing import Sequence

from omegaconf import DictConfig, OmegaConf

from nanosysid.errors import ConfigError

__all__ = ["compose", "compose_text", "load_params", "apply_overrides"]

# relative to the working directory: stages run from the root of the project they belong to
# (DVC runs them there, also in the temporary copies of `dvc exp run`)
CONF_DIR = Path("conf")
PARAMS = Path("params.yaml")


def compose_text(overrides: Sequence[str] = (), *, conf_dir: Path = CONF_DIR) -> str:
    """The YAML text DVC would write to ``params.yaml`` for these overrides."""
    from dvc.utils.hydra import compose_and_dump

    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "params.yaml"
        compose_and_dump(out, str(Path(conf_dir).resolve()), None, "config", str(Path.cwd()), list(overrides))
        return out.read_text(encoding="utf-8")


def compose(overrides: Sequence[str] = (), *, out: Path = PARAMS, conf_dir: Path = CONF_DIR) -> bool:
    """Write the composition to ``out``; return True when the file changed."""
    text = compose_text(overrides, conf_dir=conf_dir)
    out = Path(out)
    if out.exists() and out.read_text(encoding="utf-8") == text:
        return False
    tmp = out.with_name(f".{out.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(out)
    return True


def apply_overrides(cfg: DictConfig, overrides: Sequence[str]) -> DictConfig:
    """Apply Hydra override strings (``a.b=1``, ``+a.c=x``, ``~a.d``) to a config."""
    from hydra._internal.config_loader_impl import ConfigLoaderImpl
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    if not overrides:
        return cfg
    try:
        parsed = OverridesParser.create().parse_overrides(list(overrides))
        OmegaConf.set_struct(cfg, True)
        ConfigLoaderImpl._apply_overrides_to_config(parsed, cfg)
    except HydraException as e:
        raise ConfigError(f"cannot apply overrides {list(overrides)}: {e}") from None
    OmegaConf.set_struct(cfg, False)
    return cfg


def load_params(overrides: Sequence[str] = (), *, path: Path | str = PARAMS) -> DictConfig:
    """Read ``params.yaml`` and apply overrides; interpolations are resolved."""
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"{path}: not found; run `make params` to compose it from conf/")
    cfg = OmegaConf.load(path)
    cfg = apply_overrides(cfg, overrides)
    OmegaConf.resolve(cfg)
    return cfg


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m nanosysid.config", description=__doc__.split("\n")[0])
    parser.add_argument("command", choices=["compose", "check"])
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_args(argv)
    if args.command == "compose":
        changed = compose(args.overrides)
        print(f"params.yaml {'updated from' if changed else 'matches'} conf/")
        return 0
    text = compose_text(args.overrides)
    if not PARAMS.exists() or PARAMS.read_text(encoding="utf-8") != text:
        print("params.yaml differs from the composition of conf/; run `make params`", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
