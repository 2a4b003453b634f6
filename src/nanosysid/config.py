"""Configuration: ``conf/`` (Hydra) is the source of truth, ``params.yaml`` its composition.

DVC composes ``params.yaml`` from ``conf/`` on ``dvc exp run`` only; :func:`compose` does the
same composition with DVC's own function (same bytes), for ``make repro`` and the tests.
Stages read ``params.yaml`` through :func:`load_params`, with Hydra-style overrides on top.

Command line::

    python -m nanosysid.config compose [override ...]   # write params.yaml and params-rig.yaml
    python -m nanosysid.config check                    # exit 1 if either is stale
"""

from __future__ import annotations

import argparse
import ast
import fnmatch
import hashlib
import importlib
import importlib.util
import re
import sys
import tempfile
import warnings
from pathlib import Path
from typing import Sequence

import yaml
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from nanosysid.errors import ConfigError, UserError
from nanosysid.settings import check_value, leaves

__all__ = ["compose", "compose_text", "load_params", "rederive", "interpolations", "select_groups", "apply_overrides",
           "check_values", "renamed", "RENAMED"]

# relative to the working directory: stages run from the root of the project they belong to
# (DVC runs them there, also in the temporary copies of `dvc exp run`)
CONF_DIR = Path("conf")
PARAMS = Path("params.yaml")
# the rig pipeline's settings: conf/rig.yaml, the root config with the real flights' data and paths
PARAMS_RIG = Path("params-rig.yaml")
ROOTS = {"config": PARAMS, "rig": PARAMS_RIG}

# old name -> new name of the settings renamed in this release; an override under an old name
# is still accepted, with a warning, until the next one
RENAMED = {"recording": "preprocess"}


def renamed(overrides: Sequence[str]) -> list[str]:
    """The overrides with every setting or group under an old name of :data:`RENAMED` under its
    new one (``recording.sync.rate=50`` -> ``preprocess.sync.rate=50``, also with ``+``/``~`` and
    in a package ``topics@recording.topics=x``), each rename warned about (FutureWarning)."""
    out = []
    for o in overrides:
        key, eq, value = o.partition("=")
        new = key
        for old, to in RENAMED.items():
            new = re.sub(rf"(^[+~]*|@){re.escape(old)}(?=$|\.)", rf"\g<1>{to}", new)
        if new != key:
            warnings.warn(f"{key}: this setting is now {new.lstrip('+~')}; the old name is accepted until the next "
                          "release", FutureWarning, stacklevel=2)
        out.append(new + eq + value)
    return out


def compose_text(overrides: Sequence[str] = (), *, conf_dir: Path = CONF_DIR, root: str = "config") -> str:
    """The YAML text DVC would write to ``params.yaml`` for these overrides (``root``: the root
    config, ``rig`` for ``params-rig.yaml``)."""
    from dvc.utils.hydra import compose_and_dump
    from hydra.errors import HydraException

    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "params.yaml"
        try:
            compose_and_dump(out, str(Path(conf_dir).resolve()), None, root, str(Path.cwd()), list(overrides))
        except HydraException as e:  # a typo in a key, an unknown group option: Hydra's own first line
            first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            raise ConfigError(f"cannot compose {list(overrides)} from {conf_dir}: {first}") from None
        return out.read_text(encoding="utf-8")


def compose(overrides: Sequence[str] = (), *, out: Path = PARAMS, conf_dir: Path = CONF_DIR, root: str = "config") -> bool:
    """Write the composition to ``out``; return True when the file changed. A composition whose
    values the settings' rules refuse (:func:`check_values`) is not written."""
    text = compose_text(renamed(overrides), conf_dir=conf_dir, root=root)
    try:
        composed = OmegaConf.create(text)
        OmegaConf.resolve(composed)
    except OmegaConfBaseException as e:
        raise ConfigError(f"{out}: the composition of {list(overrides)} does not resolve: {str(e).splitlines()[0]}") \
            from None
    check_values(OmegaConf.to_container(composed), f"{Path(out).name} composed with {list(overrides)}")
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
    for o in overrides:
        key = o.partition("=")[0]
        if key.startswith("+"):
            # a key no stage reads would be carried silently into the run's record
            raise ConfigError(f"{o}: adds the setting {key[1:]!r}, which params.yaml does not hold; a setting is "
                              "changed with key=value, and one the configuration lacks (another log of "
                              "rig.logs.flights, say) is added in conf/, then `make params`")
    try:
        parsed = OverridesParser.create().parse_overrides(list(overrides))
    except HydraException as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise ConfigError(f"cannot read the overrides {list(overrides)}: {first} (each is key=value; quote a value "
                          "with spaces or unusual letters: key='a b')") from None
    try:
        OmegaConf.set_struct(cfg, True)
        ConfigLoaderImpl._apply_overrides_to_config(parsed, cfg)
    except HydraException as e:
        first = str(e).strip().splitlines()[0]
        raise ConfigError(f"cannot apply the overrides {list(overrides)}: {first} (the settings are those in "
                          "params.yaml)") from None
    OmegaConf.set_struct(cfg, False)
    return cfg


def select_groups(cfg: DictConfig, overrides: Sequence[str], *, conf_dir: Path = CONF_DIR) -> list[str]:
    """Apply the overrides that choose a config group's option (``launcher=slurm``: the block
    ``launcher`` becomes ``conf/launcher/slurm.yaml``), as composing would; return the others."""
    rest = []
    for o in overrides:
        key, eq, value = o.partition("=")
        name, at, package = key.partition("@")
        if eq and at and name.isidentifier() and (Path(conf_dir) / name).is_dir():
            # group@package=option: the option's file put at the package's place (topics@preprocess.topics=crazyflie)
            option = Path(conf_dir) / name / f"{value}.yaml"
            if not option.is_file():
                known = ", ".join(sorted(p.stem for p in (Path(conf_dir) / name).glob("*.yaml")))
                raise ConfigError(f"{o}: no option {value!r} in {Path(conf_dir) / name}/ (known: {known})")
            if OmegaConf.select(cfg, package) is None:
                raise ConfigError(f"{o}: params.yaml has no block {package!r} to put the option in")
            OmegaConf.update(cfg, package, OmegaConf.load(option), merge=False)
            continue
        group = Path(conf_dir) / key
        if eq and key.isidentifier() and group.is_dir() and OmegaConf.is_dict(cfg.get(key)):
            option = group / f"{value}.yaml"
            if not option.is_file():
                known = ", ".join(sorted(p.stem for p in group.glob("*.yaml")))
                raise ConfigError(f"{o}: no option {value!r} in {group}/ (known: {known})")
            cfg[key] = OmegaConf.load(option)
        else:
            rest.append(o)
    return rest


def load_params(overrides: Sequence[str] = (), *, path: Path | str = PARAMS) -> DictConfig:
    """Read ``params.yaml`` and apply overrides (a group's option, ``launcher=slurm``, as well
    as values); interpolations are resolved."""
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"{path}: not found; run `make params` to compose it from conf/")
    try:
        cfg = OmegaConf.load(path)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        at = f" (line {mark.line + 1})" if mark is not None else ""
        raise ConfigError(f"{path}: not a readable YAML file{at}: {getattr(e, 'problem', None) or e}") from None
    if not isinstance(cfg, DictConfig):
        raise ConfigError(f"{path}: holds no settings (a YAML mapping of keys to values)")
    overrides = renamed(overrides)
    rest = select_groups(cfg, overrides)  # an unknown group option is refused here, by name
    if overrides:
        rederive(cfg, _root_of(path), [o for o in overrides if o not in rest],
                 addressed=[o.partition("=")[0].lstrip("+~") for o in rest])
    cfg = apply_overrides(cfg, rest)
    try:
        OmegaConf.resolve(cfg)
    except OmegaConfBaseException as e:  # ${nope.key}: the key whose value names what is missing
        raise ConfigError(f"{path}: {_unresolved(cfg) or 'a setting'}: {str(e).splitlines()[0]}") from None
    check_values(OmegaConf.to_container(cfg), f"{path}{' with overrides' if overrides else ''}")
    return cfg


def _unresolved(cfg: DictConfig) -> str | None:
    """The key of ``cfg`` whose own value names what is missing: of the keys that do not resolve,
    the first whose interpolations name no other such key (``paths.split=${nope.key}``, not a
    model's ``split: ${paths.split}`` that only follows it)."""
    failing: list[str] = []

    def walk(node: DictConfig, prefix: str) -> None:
        for key in node.keys():
            full = f"{prefix}{key}"
            try:
                value = node[key]
            except OmegaConfBaseException:
                failing.append(full)
                continue
            if isinstance(value, DictConfig):
                walk(value, full + ".")

    walk(cfg, "")
    raw = dict(leaves(OmegaConf.to_container(cfg, resolve=False)))
    for key in failing:
        if not set(re.findall(r"\$\{([^}]+)\}", str(raw.get(key, "")))) & set(failing):
            return key
    return failing[0] if failing else None


def _root_of(path: Path) -> str:
    """The root config ``path`` is composed from (``params-rig.yaml``: ``rig``)."""
    return next((root for root, p in ROOTS.items() if Path(path).name == p.name), "config")


def interpolations(root: str = "config", groups: Sequence[str] = (), *, conf_dir: Path = CONF_DIR) -> dict[str, str]:
    """Every setting of the composition that ``conf/`` derives from another one, as the
    interpolation it is written with (``models.physics.identified``:
    ``${identify.out_dir}/params.json``); ``groups``: the config groups' choices
    (``data=csv``)."""
    conf_dir = Path(conf_dir).resolve()
    # a process that runs stages one after another (the tests, the Python API) composes conf/
    # once for them all, and again only after a file of conf/ changes (its bytes, not its mtime)
    files = hashlib.sha256(b"".join(bytes(f) + b"\0" + f.read_bytes() for f in sorted(conf_dir.rglob("*.yaml"))))
    key = (root, tuple(groups), files.hexdigest())
    if key not in _INTERPOLATIONS:
        from hydra import compose as hydra_compose
        from hydra import initialize_config_dir

        with initialize_config_dir(str(conf_dir), version_base=None):
            raw = OmegaConf.to_container(hydra_compose(config_name=root, overrides=list(groups)), resolve=False)
        _INTERPOLATIONS[key] = {k: v for k, v in leaves(raw) if isinstance(v, str) and "${" in v}
    return dict(_INTERPOLATIONS[key])


_INTERPOLATIONS: dict[tuple, dict[str, str]] = {}


def rederive(cfg: DictConfig, root: str = "config", groups: Sequence[str] = (), *, addressed: Sequence[str] = (),
             conf_dir: Path = CONF_DIR) -> list[str]:
    """Put back the interpolation of every setting of ``cfg`` (a resolved ``params.yaml``) that
    holds the value ``conf/`` derives for it, so that an override of what it is derived from
    (``identify.out_dir=x``) reaches it (``models.physics.identified``: ``x/params.json``), as it
    would have on composing. A setting given its own value (``dvc exp run -S``) keeps it, and so
    does one inside which an override of ``addressed`` sets a key (``discover.oracle.dt``).
    Returns the settings put back; none without a ``conf/``."""
    from hydra.errors import HydraException

    if not (Path(conf_dir) / f"{root}.yaml").is_file():
        return []
    try:
        template = interpolations(root, groups, conf_dir=conf_dir)
    except HydraException:  # a composition conf/ cannot make: the file's values stand
        return []
    derived = {k: v for k, v in template.items()
               if OmegaConf.select(cfg, k, default=_ABSENT) is not _ABSENT
               and not any(a.startswith(k + ".") for a in addressed)}
    trial = cfg.copy()
    for key, text in derived.items():
        OmegaConf.update(trial, key, text, merge=False, force_add=True)
    back = []
    for key, text in derived.items():
        try:
            same = OmegaConf.select(trial, key, throw_on_resolution_failure=True) == OmegaConf.select(cfg, key)
        except Exception:  # an interpolation that no longer resolves here: the file's value stands
            same = False
        if same:
            back.append(key)
    for key in back:
        OmegaConf.update(cfg, key, derived[key], merge=False)
    return back


_ABSENT = object()


def check_values(cfg: dict, where: str = "params.yaml") -> None:
    """Refuse a setting of the wrong kind (``eval.horizon=abc``, ``substeps=0``,
    ``vehicle.mass=heavy``) or a filter cut-off at or above the Nyquist frequency.

    Raises:
        ConfigError: naming the key, the value and what it must be.
    """
    for key, value in leaves(cfg):
        check_value(key, value, where=where)
    filt = (cfg.get("preprocess") or {}).get("filter") or {}
    nyquist = filt.get("rate", 0) / 2
    for band in ("position", "velocity", "acceleration", "motors", "quaternion"):
        if band in filt and filt[band] >= nyquist:
            raise ConfigError(f"{where}: preprocess.filter.{band} = {filt[band]} Hz is at or above the Nyquist "
                              f"frequency {nyquist:g} Hz of preprocess.filter.rate")
    _check_protocol(cfg, where)
    _check_choices(cfg, where)
    band = ((cfg.get("preprocess") or {}).get("sync") or {}).get("xcorr_band")
    rate = ((cfg.get("preprocess") or {}).get("sync") or {}).get("rate", 0)
    if band is not None and (len(band) != 2 or not band[0] < band[1] < rate / 2):
        raise ConfigError(f"{where}: preprocess.sync.xcorr_band must be two frequencies, low < high < "
                          f"{rate / 2:g} Hz (half preprocess.sync.rate), got {band!r}")


# the benchmark's longest horizon (the paper's protocol: MAE at h = 1..50)
PROTOCOL_HORIZON = 50

# a model's optimiser and scheduler are built from ``_target_``: only torch's own classes
_TARGETS = [("models.*.train.optimizer._target_", "torch.optim"),
            ("models.*.train.scheduler._target_", "torch.optim.lr_scheduler")]


def _check_choices(cfg: dict, where: str) -> None:
    """The classes an optimiser or scheduler names (torch's own) and the report's horizons
    against the protocol's."""
    for key, value in leaves(cfg):
        for pattern, module in _TARGETS:
            if fnmatch.fnmatchcase(key, pattern):
                mod, _, name = str(value).rpartition(".")
                if mod != module or not name or name not in _module_names(module):
                    raise ConfigError(f"{where}: {key} must name a class of {module} (e.g. {module}."
                                      f"{'Adam' if module == 'torch.optim' else 'ReduceLROnPlateau'}), got {value!r}")
    ev = cfg.get("eval") or {}
    horizon, shown = ev.get("horizon"), ev.get("table_horizons") or []
    longest = max(horizon, PROTOCOL_HORIZON) if isinstance(horizon, int) else PROTOCOL_HORIZON
    if any(isinstance(h, int) and h > longest for h in shown):
        # within the protocol's horizons, those beyond a shortened eval.horizon are left out of the
        # tables (a quick run), and the tables say so
        raise ConfigError(f"{where}: eval.table_horizons {shown} go beyond the protocol's {PROTOCOL_HORIZON} steps "
                          f"and eval.horizon = {horizon}; choose horizons up to {longest}")


def _module_names(module: str) -> set[str]:
    """The names a module defines or imports at its top level, read from its source without
    importing it where it is not loaded yet: every stage checks the whole config, and loading
    torch for the check alone costs a stage that never uses torch seconds."""
    if module in sys.modules:
        return set(vars(sys.modules[module]))
    top, *rest = module.split(".")
    spec = importlib.util.find_spec(top)
    locations = list(spec.submodule_search_locations or []) if spec is not None else []
    base = Path(locations[0]).joinpath(*rest) if locations else None
    source = next((p for p in (base / "__init__.py", base.with_suffix(".py")) if p.is_file()), None) if base else None
    if source is None:
        return set(vars(importlib.import_module(module)))
    names = set()
    for node in ast.parse(source.read_text(encoding="utf-8")).body:
        if isinstance(node, (ast.ClassDef, ast.FunctionDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names.update((a.asname or a.name).split(".")[0] for a in node.names)
        elif isinstance(node, ast.Assign):
            names.update(t.id for t in node.targets if isinstance(t, ast.Name))
    return names


def _check_protocol(cfg: dict, where: str) -> None:
    """The settings the data's rate fixes: the benchmark's flights are at 100 Hz, so the sync and
    filter grids, every model's step and the oracle's are 10 ms."""
    from nanosysid.dataio import SAMPLE_PERIOD, check_step

    rate = 1 / SAMPLE_PERIOD
    rec = cfg.get("preprocess") or {}
    for key in ("sync", "filter"):
        r = (rec.get(key) or {}).get("rate")
        if r is not None and abs(r - rate) > 1e-9 * rate:
            raise ConfigError(f"{where}: preprocess.{key}.rate = {r:g} Hz; the benchmark's flights are at {rate:g} Hz "
                              "(every model and the protocol's horizons assume it)")
    steps = [(f"models.{m}.dt", (o or {}).get("dt")) for m, o in (cfg.get("models") or {}).items() if isinstance(o, dict)]
    steps.append(("discover.oracle.dt", ((cfg.get("discover") or {}).get("oracle") or {}).get("dt")))
    for key, dt in steps:
        if dt is not None:  # a model without a step of its own (a network, an external predictor)
            check_step(dt, f"{where}: {key}")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m nanosysid.config", description=__doc__.split("\n")[0])
    parser.add_argument("command", choices=["compose", "check"])
    parser.add_argument("overrides", nargs="*")
    args = parser.parse_args(argv)
    if args.command == "compose":
        try:
            texts = {out: compose_text(renamed(args.overrides), root=root) for root, out in ROOTS.items()}
            for root, out in ROOTS.items():  # every composition checked before either file is written
                composed = OmegaConf.create(texts[out])
                OmegaConf.resolve(composed)
                check_values(OmegaConf.to_container(composed), f"{out.name} composed with {args.overrides}")
            for root, out in ROOTS.items():
                changed = compose(args.overrides, out=out, root=root)
                print(f"{out} {'updated from' if changed else 'matches'} conf/")
        except (UserError, OmegaConfBaseException) as e:
            print(f"error: {str(e).splitlines()[0]}", file=sys.stderr)
            return 2
        return 0
    for root, out in ROOTS.items():
        text = compose_text(renamed(args.overrides), root=root)
        if not out.exists() or out.read_text(encoding="utf-8") != text:
            print(f"{out} differs from the composition of conf/; run `make params`", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
