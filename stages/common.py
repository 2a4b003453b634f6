"""What every stage script shares: the command line, the config, and reading the config's
blocks into the library's plain arguments.

Every stage runs as ``python -m stages.<name> [NAME] [key=value ...]``: an optional
positional name (the ``foreach`` item, e.g. the model) and Hydra-style overrides applied on
top of ``params.yaml``. A user's mistake (:class:`nanosysid.errors.UserError`) ends the stage
with one message and exit code 2.
"""

from __future__ import annotations

import argparse
import errno
import logging
import os
import signal
import sys
from pathlib import Path
from typing import Any, Callable, Sequence

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import ConfigAttributeError, ConfigKeyError

from nanosysid.config import load_params
from nanosysid.dataio import Flight
from nanosysid.errors import ConfigError, UserError
from nanosysid.guard import stage_name, stage_run
from nanosysid.vehicle import Vehicle

__all__ = ["run_stage", "plain", "vehicle_of", "model_options", "pick_flight"]

log = logging.getLogger("nanosysid")


def run_stage(
    main: Callable[..., Any],
    *,
    description: str,
    name_arg: str | None = None,
    argv: Sequence[str] | None = None,
) -> int:
    """Parse the command line, load the config and call ``main(cfg)`` or ``main(cfg, name)``."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog=_settings_help(main, argv) if {"-h", "--help"} & set(argv) else None)
    if name_arg:
        parser.add_argument(name_arg)
    parser.add_argument("overrides", nargs="*", help="Hydra-style overrides, e.g. eval.horizon=20")
    parser.add_argument("--params", default=None, help="params file (default: params.yaml)")
    args = parser.parse_intermixed_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    # the stage's name in dvc.yaml: the one that runs this module on this params file (under
    # `python -m` the module is __main__); the rig pipeline's run the same modules
    spec = getattr(sys.modules.get(main.__module__), "__spec__", None)
    module = spec.name if spec is not None else main.__module__
    stage = stage_name(module, args.params) + (f"@{getattr(args, name_arg)}" if name_arg else "")
    try:
        kw = {"path": args.params} if args.params else {}
        cfg: DictConfig = load_params(args.overrides, **kw)
        with stage_run(stage, cfg), _stopped_by_signals():
            if name_arg:
                main(cfg, getattr(args, name_arg))
            else:
                main(cfg)
    except UserError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except (ConfigAttributeError, ConfigKeyError) as e:  # a setting the stage reads, deleted (~key) or absent
        key = getattr(e, "full_key", None) or str(e).splitlines()[0]
        deleted = [o for o in args.overrides if o.startswith("~") and str(key).startswith(o[1:].partition("=")[0])]
        print(f"error: the setting {key!r} is missing" + (f" (deleted by {deleted[0]})" if deleted else "")
              + f"; the {stage} stage reads it", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"error: {os_fault(e)}", file=sys.stderr)
        return 2
    except Stopped as e:
        print(f"error: {stage} stopped by {e.name}; its outputs were not written ({_before_the_run()})",
              file=sys.stderr)
        return 128 + e.signum
    return 0


def _before_the_run() -> str:
    """Where a stopped run leaves the last run's outputs: as they were, except under DVC, which
    removes a stage's outputs before running it (``DVC_STAGE`` is set for the command)."""
    under = os.environ.get("DVC_STAGE")
    if under:
        return (f"DVC removed the last run's before starting it: `dvc checkout {under}` brings them back from DVC's "
                "cache, `dvc repro` reruns the stage")
    return "the last run's, if any, are as they were"


class Stopped(BaseException):
    """A stage stopped by a signal: a BaseException, so that no library's ``except Exception``
    (Lightning's fit loop, a retry) takes it for an error it may handle and carry on from."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum, self.name = signum, signal.Signals(signum).name


class _stopped_by_signals:
    """Inside the block, SIGTERM, SIGINT and SIGHUP (a closed terminal or ssh session) raise
    :class:`Stopped`: the stage unwinds through its
    outputs' guards (nothing half-written is renamed into place) and exits 128 + the signal.
    Lightning keeps a SIGTERM handler found in place and calls it after its own."""

    def __enter__(self):
        def stop(signum, frame):
            raise Stopped(signum)

        # a signal the caller ignores (SIGINT of a job started in the background) stays ignored
        self._before = {s: signal.signal(s, stop) for s in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)
                        if signal.getsignal(s) is not signal.SIG_IGN}
        return self

    def __exit__(self, *exc) -> None:
        for s, h in self._before.items():
            signal.signal(s, h)


def _settings_help(main: Callable[..., Any], argv: Sequence[str]) -> str:
    """What ``--help`` lists after the arguments: the settings the stage reads (its ``params`` in
    ``dvc.yaml``, each one settable as ``key=value``) and the models it may be given."""
    import yaml

    params = next((argv[i + 1] for i, a in enumerate(argv[:-1]) if a == "--params"), None)
    spec = getattr(sys.modules.get(main.__module__), "__spec__", None)
    stage = stage_name(spec.name if spec is not None else main.__module__, params)
    try:
        body = (yaml.safe_load(open("dvc.yaml")) or {}).get("stages", {}).get(stage, {})
        keys = [str(k).replace("${key}", "<model>").replace("${item}", "<model>")
                for k in body.get("do", body).get("params", [])]
        models = list((yaml.safe_load(open(params or "params.yaml")) or {}).get("models", {}))
        configs = sorted(p.stem for p in Path("conf", "model").glob("*.yaml"))
    except OSError:
        return "(run it in the project: its dvc.yaml and params.yaml name the settings)"
    return "\n".join([f"settings it reads (dvc.yaml's params of `{stage}`; set any as key=value, the whole block "
                      "is under that key in params.yaml):", *(f"  {k}" for k in keys),
                      f"models configured: {', '.join(models)}",
                      f"model configs (conf/model/, model@models.<name>=<config>): {', '.join(configs)}"])


_HINTS = {
    errno.EACCES: "no permission: choose a path you may write, or change its permissions",
    errno.EPERM: "not permitted: choose a path you may write",
    errno.EROFS: "the file system is read-only: choose an output on a writable disk",
    errno.ENOSPC: "the disk is full: free space or choose an output on another disk",
    errno.EDQUOT: "the disk quota is exhausted: free space or choose another disk",
    errno.ENOTDIR: "a part of the path is a file, not a folder: choose another path",
    errno.EISDIR: "it is a folder where a file is wanted: choose another path",
    errno.ENOENT: "no such file or folder: check the path (quote a path with spaces in an override: key='a b')",
    errno.ENAMETOOLONG: "the name is too long: choose a shorter path",
}


def os_fault(e: OSError) -> str:
    """One line for an operating-system fault: the path, what happened, what to do."""
    where = e.filename if e.filename is not None else "(no path)"
    return f"{where}: {e.strerror or e}; " + _HINTS.get(e.errno, "check the path and the disk")


def plain(node: Any) -> Any:
    """A config node as plain Python data (dicts, lists, scalars), interpolations resolved."""
    return OmegaConf.to_container(node, resolve=True) if OmegaConf.is_config(node) else node


def vehicle_of(cfg: DictConfig) -> Vehicle:
    """The nominal vehicle of ``conf/vehicle``."""
    try:
        return Vehicle.from_mapping(plain(cfg.vehicle))
    except (KeyError, TypeError, ValueError) as e:
        raise ConfigError(f"vehicle: {e}") from None


def model_options(cfg: DictConfig, name: str) -> dict[str, Any]:
    """The ``models.<name>`` block as plain data."""
    if name not in cfg.models:
        raise ConfigError(f"models.{name}: no such model in the config (known: {', '.join(cfg.models)})")
    return plain(cfg.models[name])


def pick_flight(flights: list[Flight], name: str | None, key: str) -> Flight:
    """The flight called ``name`` (a prefix of its file name will do), the first one when None."""
    if name is None:
        return flights[0]
    hits = [f for f in flights if f.name == name or f.name.startswith(name)]
    if not hits:
        raise ConfigError(f"{key}: no test flight named {name!r} (there are: {', '.join(f.name for f in flights)})")
    return hits[0]


