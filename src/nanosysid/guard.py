"""One guard for every output a stage writes, file or folder.

Before a file or folder is written (:func:`nanosysid.dataio.atomic_file`,
:func:`nanosysid.dataio.atomic_dir`) the guard

- refuses an output equal to, inside or containing an input of the stage (its DVC dependencies,
  resolved with the run's settings, and any the caller names) or another stage's declared output;
- takes the output's lock, so one run writes it at a time (a second run is told which holds it);
- refuses to replace an existing path it cannot prove a run of *this* stage wrote: the record
  beside it (``.<name>.nanosysid``) names the stage, the output and, for a folder, the files
  it wrote; a file or folder DVC restored is the stage's when ``dvc.lock`` records it for that
  stage. A file of the user's inside a stage's folder is named, never deleted;
- removes only its own temporaries (``.<name>.nanosysid-*``), under the lock.

The stage is the one :func:`stage_run` opened (``stages.common.run_stage`` opens it); outside a
stage (the Python API) the writer is ``python``.
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import fcntl
import glob
import hashlib
import json
import os
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import yaml

from nanosysid.errors import ConfigError

__all__ = ["Claim", "claim", "stage_run", "stage_name", "declared", "record_path", "file_md5", "API", "PIPELINE_FILES"]

API = "python"  # the writer outside any stage
TMP = "nanosysid-"  # our temporaries: .<name>.nanosysid-<random>.tmp / .old
_SUFFIX = ".nanosysid"  # the record and lock beside an output
OWNER = ".nanosysid-output"  # the mark inside a folder a stage wrote: which stage, where, which files
_MARK_HEAD = "written by a nanosysid stage; the stage replaces this folder as a whole\n"


@dataclass
class _Run:
    stage: str
    inputs: tuple[Path, ...] = ()
    outputs: tuple[Path, ...] = ()
    others: dict[Path, str] = field(default_factory=dict)  # other stages' outputs -> their stage
    locked: dict[str, str] = field(default_factory=dict)  # dvc.lock: output path -> md5 (this stage's)
    # the outputs written so far, as what puts each back as it was; a failed run undoes them
    undo: list[Callable[[], None]] = field(default_factory=list)
    aside: list[Path] = field(default_factory=list)  # the versions replaced, removed when the run ends well


_SCRATCH: list[Path] = []  # the temporary folders being written (what is written inside is theirs)


_run: contextvars.ContextVar[_Run | None] = contextvars.ContextVar("nanosysid_stage_run", default=None)


def _resolve(p: str | os.PathLike) -> Path:
    return Path(os.path.abspath(os.fspath(p)))


def _overlaps(a: Path, b: Path) -> str | None:
    if a == b:
        return "is"
    if b in a.parents:
        return "lies inside"
    if a in b.parents:
        return "contains"
    return None


_VAR = re.compile(r"\$\{([^}]+)\}")


def _interpolate(text: str, cfg: Any, scope: dict[str, Any]) -> str | None:
    from omegaconf import OmegaConf

    def one(m: re.Match) -> str:
        expr = m.group(1).strip()
        head, _, rest = expr.partition(".")
        if head in scope:
            v = scope[head]
            for part in filter(None, rest.split(".")):
                v = v[part]
        else:
            v = OmegaConf.select(cfg, expr, throw_on_missing=False)
        if v is None or isinstance(v, (dict, list)) or OmegaConf.is_config(v):
            raise KeyError(expr)
        return str(v)

    try:
        return _VAR.sub(one, text)
    except (KeyError, TypeError, IndexError):
        return None


# the benchmark's pipeline files, the simulated world's and the real flights': every stage of
# either is a stage whose outputs the guard knows
PIPELINE_FILES = ("dvc.yaml", "rig/dvc.yaml")


def _pipeline_stages(files: Sequence[str | os.PathLike]) -> list[tuple[str, dict, Path, Path]]:
    """``(name, entry, working directory, lock file)`` of every stage of the pipeline ``files``
    that exist (a stage's ``wdir`` is relative to its file)."""
    got = []
    for f in map(Path, files):
        if not f.is_file():
            continue
        for name, st in ((_yaml(f.read_text()) or {}).get("stages") or {}).items():
            got.append((name, st, f.parent / str(st.get("do", st).get("wdir", ".")), f.parent / "dvc.lock"))
    return got


def _pipeline_files(root: Path, dvc_yaml: str | os.PathLike | Sequence[str | os.PathLike] | None) -> list[Path]:
    if dvc_yaml is None:
        return [root / f for f in PIPELINE_FILES]
    return [Path(dvc_yaml)] if isinstance(dvc_yaml, (str, os.PathLike)) else [Path(f) for f in dvc_yaml]


def declared(cfg: Any, dvc_yaml: str | os.PathLike | Sequence[str | os.PathLike] | None = None,
             stage: str | None = None) -> dict[str, tuple[list[str], list[str]]]:
    """Every stage of ``dvc_yaml`` (``name`` or ``name@item``; by default the benchmark's pipeline
    files, :data:`PIPELINE_FILES`): its dependencies and outputs, the
    paths resolved with ``cfg`` (the run's settings, overrides included). Empty without the file.
    The stages of another pipeline (whose command reads another params file than ``stage``'s, or
    than ``params.yaml`` without ``stage``: ``--params``) are resolved with their own file's
    settings, as DVC resolves each pipeline file with its own ``vars``."""
    entries = _pipeline_stages(_pipeline_files(Path("."), dvc_yaml))
    return {k: ([p for p, _ in d], [p for p, _ in o]) for k, (d, o) in _declared(cfg, entries, stage).items()}


_PARAMS_ARG = re.compile(r"--params[= ](\S+)")
DEFAULT_PARAMS = "params.yaml"


def _params_of(cmd: str) -> str:
    """The params file a stage's command reads."""
    m = _PARAMS_ARG.search(cmd)
    return m.group(1) if m else DEFAULT_PARAMS


def stage_name(module: str, params: str | os.PathLike | None,
               dvc_yaml: str | os.PathLike | Sequence[str | os.PathLike] | None = None) -> str:
    """The name in ``dvc_yaml`` (by default the benchmark's pipeline files) of the stage that runs
    ``python -m <module>`` on ``params`` (the rig pipeline's ``rig_sync`` for ``stages.sync`` on
    ``params-rig.yaml``); the module's last part where no stage does."""
    want = _resolve(params or DEFAULT_PARAMS)
    for name, st, wdir, _ in _pipeline_stages(_pipeline_files(Path("."), dvc_yaml)):
        cmd = str(st.get("do", st).get("cmd", ""))
        if re.search(rf"python -m {re.escape(module)}(\s|$)", cmd) and _resolve(wdir / _params_of(cmd)) == want:
            return name
    return module.rpartition(".")[2]


def _declared(cfg: Any, entries: list[tuple[str, dict, Path, Path]], stage: str | None = None
              ) -> dict[str, tuple[list[tuple[str, str]], list[tuple[str, str]]]]:
    from omegaconf import OmegaConf

    out: dict[str, tuple[list[tuple[str, str]], list[tuple[str, str]]]] = {}
    others: dict[Path, Any] = {}

    def params_file(st: dict, wdir: Path) -> Path:
        return _resolve(wdir / _params_of(str(st.get("do", st).get("cmd", ""))))

    if stage is None:  # cfg is params.yaml's
        run_params = _resolve(Path(DEFAULT_PARAMS))
    else:
        base = next(((st, w) for n, st, w, _ in entries if n == stage.partition("@")[0]), None)
        run_params = None if base is None else params_file(*base)
    for name, st, wdir, _ in entries:
        own = params_file(st, wdir)
        if run_params is not None and own != run_params:
            if own not in others:
                try:
                    others[own] = OmegaConf.load(own)
                except (OSError, ValueError):  # a pipeline whose settings are not composed here
                    others[own] = None
            if others[own] is None:
                continue
            stage_cfg = others[own]
        else:
            stage_cfg = cfg
        out.update(_declared_stage(name, st, stage_cfg))
    return out


def _declared_stage(name: str, st: dict, cfg: Any) -> dict[str, tuple[list[tuple[str, str]], list[tuple[str, str]]]]:
    """One entry of ``dvc.yaml``'s stages (each item of a ``foreach``) resolved with ``cfg``."""
    from omegaconf import OmegaConf

    if "foreach" not in st:
        return {name: _paths(st, cfg, {})}
    items = OmegaConf.select(cfg, _VAR.fullmatch(str(st["foreach"])).group(1), throw_on_missing=False) \
        if isinstance(st["foreach"], str) and _VAR.fullmatch(st["foreach"]) else st["foreach"]
    items = OmegaConf.to_container(items, resolve=True) if OmegaConf.is_config(items) else items
    pairs = items.items() if isinstance(items, dict) else ((i, i) for i in (items or []))
    return {f"{name}@{key}": _paths(st["do"], cfg, {"key": key, "item": item}) for key, item in pairs}


def _paths(st: dict, cfg: Any, scope: dict) -> tuple[list[tuple[str, str]], list[tuple[str, str]]]:
    def each(entries) -> list[tuple[str, str]]:
        got = []
        for e in entries or []:
            p = e if isinstance(e, str) else next(iter(e))
            r = _interpolate(p, cfg, scope)
            if r:
                got.append((r, p))
        return got

    outs = [*each(st.get("outs")), *each(st.get("metrics")), *each(st.get("plots"))]
    return each(st.get("deps")), outs


def _yaml(text: str) -> Any:
    """``yaml.safe_load`` by libyaml where PyYAML has it: every stage reads dvc.lock, 200 kB, which
    the pure-Python parser takes 0.4 s for."""
    return yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))


def _lock_outs(stage: str, dvc_lock: Path) -> dict[str, str]:
    if not dvc_lock.is_file():
        return {}
    try:
        lock = _yaml(dvc_lock.read_text()) or {}
    except yaml.YAMLError:
        return {}
    st = (lock.get("stages") or {}).get(stage) or {}
    return {str(_resolve(o["path"])): o.get("md5", "") for o in st.get("outs", []) if "path" in o}


@contextlib.contextmanager
def stage_run(stage: str, cfg: Any = None, root: str | os.PathLike = ".") -> Iterator[None]:
    """Everything written inside is written by ``stage`` (``name`` or ``name@item``), whose
    inputs and outputs the benchmark's pipeline files in ``root`` declare (:data:`PIPELINE_FILES`,
    resolved with ``cfg``; the other pipeline's stages with their own params file)."""
    root = Path(root)
    entries = _pipeline_stages([root / f for f in PIPELINE_FILES])
    layout = _declared(cfg, entries, stage) if cfg is not None else {}
    items = [name for name in layout if name.startswith(f"{stage}@")]
    if stage not in layout and len(items) == 1:
        # a stage run once per item of a list whose command is the same for each (quality@sim)
        stage = items[0]
    deps, outs = layout.get(stage, ([], []))
    others = {_resolve(o): name for name, (_, os_) in layout.items() if name != stage for o, _ in os_}
    lock = next((lk for n, _, _, lk in entries if n == stage.partition("@")[0]), root / "dvc.lock")
    run = _Run(stage, tuple(_resolve(d) for d, _ in deps), tuple(_resolve(o) for o, _ in outs), others,
               _lock_outs(stage, lock))
    # every declared output against the inputs and the other stages' outputs before any work: a
    # wrong path fails in a second, not after training (what exists there is checked on writing)
    for out, template in outs:
        setting = ", ".join(m.group(1) for m in _VAR.finditer(template) if m.group(1).split(".")[0] not in ("item", "key"))
        try:
            _check_inputs(Path(out), run.inputs, "the stage's input")
            _check_others(Path(out), run.others)
        except ConfigError as e:
            raise ConfigError(f"{e}" + (f" (the setting {setting})" if setting else "")) from None
    token = _run.set(run)
    try:
        yield
    except BaseException:
        # a stage writes all of its outputs or none: the ones written before the failure go back
        for step in reversed(run.undo):
            with contextlib.suppress(OSError):
                step()
        raise
    else:
        for old in run.aside:  # each a folder holding the replaced version
            shutil.rmtree(old, ignore_errors=True)
    finally:
        _run.reset(token)


def record_path(path: Path) -> Path:
    """The record (and lock) beside an output."""
    return path.parent / f".{path.name}{_SUFFIX}"


def file_md5(path: Path) -> str:
    """The MD5 of a file's bytes (hex), read a megabyte at a time."""
    h = hashlib.md5()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _read_mark(path: Path) -> dict | None:
    """The stage, path and files of a folder's mark :data:`OWNER`; None where there is none or it
    says nothing of them (then the folder is not known to be a stage's)."""
    try:
        head, _, body = path.read_text().partition("\n")
        mark = json.loads(body)
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    ok = head + "\n" == _MARK_HEAD and isinstance(mark, dict) and isinstance(mark.get("path"), str)
    return mark if ok else None


def _files(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if not p.is_dir())


@dataclass
class Claim:
    """An output being written: its path, the writer, and the held lock."""
    path: Path
    kind: str  # "file" or "folder"
    stage: str
    fd: int | None = None
    scratch: bool = False  # inside a folder being written: the folder's guard covers it
    before: str | None = None  # the record's text before this write (None: there was none)
    made: tuple[Path, ...] = ()  # the parent folders this write created, deepest first

    def temporary(self) -> Path:
        """A new temporary beside the output (ours by name, so a later run may remove it)."""
        import tempfile

        if self.kind == "folder":
            tmp = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.{TMP}", suffix=".tmp", dir=self.path.parent))
            _SCRATCH.append(_resolve(tmp))
            return tmp
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.{TMP}", suffix=".tmp", dir=self.path.parent)
        os.close(fd)
        return Path(tmp)

    def done(self, tmp: Path) -> None:
        """Record what was written (before the swap: the record never names what is not there)."""
        if self.scratch or self.fd is None:
            return
        # the name only: the record lies beside the output, and a moved tree keeps its records true
        rec = {"stage": self.stage, "output": self.path.name, "kind": self.kind}
        if self.kind == "folder":
            rec["files"] = _files(tmp)
        else:
            rec["md5"] = file_md5(tmp)
        os.ftruncate(self.fd, 0)
        os.pwrite(self.fd, (json.dumps(rec, indent=1, sort_keys=True) + "\n").encode(), 0)

    def mark(self, tmp: Path) -> str:
        """The text of the mark :data:`OWNER` of the folder being written in ``tmp``: the stage, the
        output's name and the files, so that a copy of the folder under another name (``cp -r``),
        or one whose record beside it was lost, is not taken for the stage's own output there.
        The name only, as in the record: the same output written anywhere has the same bytes."""
        files = [f for f in _files(tmp) if f != OWNER]
        return _MARK_HEAD + json.dumps({"stage": self.stage, "path": self.path.name, "files": files},
                                       sort_keys=True) + "\n"

    def swap(self, tmp: Path) -> None:
        """Put the written ``tmp`` in the output's place. Inside a stage run the version it
        replaces is kept aside (a rename: no space needed) until the run ends, so that a run
        failing at a later output puts this one back as it was, its record too; elsewhere a
        file is replaced in one rename and a folder's old version removed once the new is in."""
        import tempfile

        run = _run.get()
        undoable = run is not None and not self.scratch
        old = None
        if os.path.lexists(self.path) and (undoable or self.kind == "folder"):
            old = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.{TMP}", suffix=".old", dir=self.path.parent))
            try:
                os.replace(self.path, old / "x")
            except OSError:
                old.rmdir()  # the output could not be moved aside (immutable, say): it stays as it was
                raise
        try:
            os.replace(tmp, self.path)
        except OSError:
            if old is not None:  # the old version back in its place
                os.replace(old / "x", self.path)
                old.rmdir()
            raise
        if not undoable:
            if old is not None:
                shutil.rmtree(old)
            return
        if old is not None:
            run.aside.append(old)
        rec, before, made = record_path(self.path), self.before, self.made

        def back() -> None:
            if self.path.is_dir() and not self.path.is_symlink():
                shutil.rmtree(self.path)
            else:
                self.path.unlink(missing_ok=True)
            if old is not None:
                os.replace(old / "x", self.path)
                old.rmdir()
            if before is None:
                rec.unlink(missing_ok=True)
            else:
                rec.write_text(before)
            for folder in made:
                with contextlib.suppress(OSError):
                    folder.rmdir()  # only where it is empty again

        run.undo.append(back)

    def forget(self, tmp: Path) -> None:
        """The temporary folder is swapped in or removed: what is written there now is checked."""
        if _resolve(tmp) in _SCRATCH:
            _SCRATCH.remove(_resolve(tmp))


def _read_text(path: Path) -> str | None:
    try:
        return path.read_text()
    except (OSError, UnicodeDecodeError):
        return None


def _read_record(rec: Path) -> dict[str, Any] | None:
    try:
        d = json.loads(rec.read_text() or "null")
    except (OSError, ValueError):
        return None
    return d if isinstance(d, dict) else None


def _check_inputs(path: Path, inputs: Sequence[Path], what: str) -> None:
    # as written and with every link followed: a link may lead an output onto an input
    outs = {_resolve(path), Path(os.path.realpath(path))}
    for inp in inputs:
        for out in outs:
            for i in {inp, Path(os.path.realpath(inp))}:
                rel = _overlaps(out, i)
                if rel:
                    raise ConfigError(f"{path}: the output {rel} {what} {inp}; choose another output path")


def _restored(path: Path, run: _Run | None) -> bool:
    """Whether ``path`` holds what ``dvc.lock`` records for the running stage (DVC put it there)."""
    md5 = run.locked.get(str(_resolve(path))) if run is not None else None
    return bool(md5) and md5 == file_md5(path)


def _check_others(path: Path, others: dict[Path, str]) -> None:
    here = _resolve(path)
    for other, name in others.items():
        rel = _overlaps(here, other)
        if rel:
            raise ConfigError(f"{path}: the output {rel} {other}, the output of stage {name}; choose another path")


def _ours(path: Path, kind: str, stage: str, rec: dict | None, run: _Run | None) -> None:
    """Raise unless ``path`` (existing) was written by ``stage`` as a ``kind``."""
    if kind == "folder" and not path.is_dir():
        raise ConfigError(f"{path}: is a file where the stage writes a folder; move it away or choose another path")
    if kind == "file" and path.is_dir():
        raise ConfigError(f"{path}: is a folder where the stage writes a file; move it away or choose another path")
    if rec is not None and rec.get("output") is not None:
        if rec.get("stage") != stage:
            raise ConfigError(f"{path}: written by stage {rec.get('stage')}, not by {stage}; refusing to replace "
                              "another stage's output (choose another path)")
        if kind == "file" and rec.get("md5") not in (None, file_md5(path)) and not _restored(path, run):
            raise ConfigError(f"{path}: changed since stage {stage} wrote it; refusing to overwrite it "
                              "(move it away to keep it, or delete it)")
        if kind == "folder":
            known = set(rec.get("files") or [])
            foreign = [f for f in _files(path) if f not in known]
            if foreign:
                raise ConfigError(f"{path / foreign[0]}: not written by stage {stage} (" + (
                    f"and {len(foreign) - 1} more " if len(foreign) > 1 else "") +
                    "in its output folder); move it out, the stage replaces the folder as a whole")
        return
    # no record: what DVC restored, or an older run's output
    if kind == "file":
        if _restored(path, run):
            return
        raise ConfigError(f"{path}: exists and no run of stage {stage} wrote it; refusing to overwrite it "
                          "(move it away or choose another path)")
    # a folder a stage marked (restored by DVC, whose checkout brings no record): the stage's own
    # only where its mark says this stage wrote it here, and holds no file the stage did not write
    if not any(path.iterdir()):
        return
    mark = _read_mark(path / OWNER)
    if mark is not None:
        if mark.get("stage") != stage:
            raise ConfigError(f"{path}: marked as the output of stage {mark.get('stage')}, not of {stage}; refusing to "
                              "replace it (choose a new or empty folder)")
        if mark["path"] != path.name:
            raise ConfigError(f"{path}: a copy of stage {stage}'s output {mark['path']} (its mark says so), with no "
                              "record of a run writing here; refusing to replace it (choose a new or empty folder)")
        foreign = [f for f in _files(path) if f != OWNER and f not in set(mark.get("files") or [])]
        if foreign:
            raise ConfigError(f"{path / foreign[0]}: not written by stage {stage} (" + (
                f"and {len(foreign) - 1} more " if len(foreign) > 1 else "") +
                "in its output folder); move it out, the stage replaces the folder as a whole")
        return
    raise ConfigError(f"{path}: holds files no run of stage {stage} wrote; refusing to replace it "
                      "(choose a new or empty folder)")


def _disk_full(e: BaseException) -> int | None:
    """ENOSPC or EDQUOT where ``e`` says the disk is full (an OSError, or a library's error that
    carries the errno only in its text), else None."""
    if isinstance(e, OSError) and e.errno in (errno.ENOSPC, errno.EDQUOT):
        return e.errno
    text = str(e)
    if isinstance(e, OSError) and ("No space left on device" in text or f"errno {errno.ENOSPC}]" in text):
        return errno.ENOSPC
    return None


@contextlib.contextmanager
def claim(path: str | os.PathLike, kind: str, *, inputs: Sequence[str | os.PathLike] = (),
          replace: bool = False) -> Iterator[Claim]:
    """Hold ``path`` for writing as a ``kind`` (``"file"``, ``"folder"``): checked, locked, and
    cleared of our own leftovers. ``replace``: a file the project edits in place (the README)."""
    path = Path(path)
    run = _run.get()
    stage = run.stage if run is not None else API
    here = _resolve(path)
    if any(s in here.parents for s in _SCRATCH):
        path.parent.mkdir(parents=True, exist_ok=True)
        yield Claim(path, kind, stage, scratch=True)
        return
    if os.path.islink(path):
        raise ConfigError(f"{path}: a link (to {os.readlink(path)}); a stage replaces its output as a whole, which "
                          "would put a plain file or folder where the link was: give the link's target, or another path")
    _check_inputs(path, [_resolve(i) for i in inputs], "the input")
    if run is not None:
        _check_inputs(path, run.inputs, "the stage's input")
        _check_others(path, run.others)
    made = tuple(p for p in [path.parent, *path.parent.parents] if not os.path.lexists(p))
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise ConfigError(f"{path}: a parent of the output is a file; choose another path") from None
    rec_path = record_path(path)
    created = not os.path.lexists(rec_path)
    before = None if created else _read_text(rec_path)
    fd = os.open(rec_path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as e:
        os.close(fd)
        if e.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
            raise
        holder = (_read_record(rec_path) or {}).get("writing", "another run")
        raise ConfigError(f"{path}: being written by {holder}; wait for it to finish, or choose another output") from None
    c = Claim(path, kind, stage, fd, before=before, made=made)
    rec = _read_record(rec_path)
    try:
        if path.exists() and not replace:
            _ours(path, kind, stage, rec, run)
        # who is writing, for a second run to name (the record proper is written on success)
        os.ftruncate(fd, 0)
        kept = {k: v for k, v in (rec or {}).items() if k != "writing"}
        os.pwrite(fd, (json.dumps({**kept, "writing": f"stage {stage} (process {os.getpid()})"}, sort_keys=True)
                       + "\n").encode(), 0)
        aside = {_resolve(a) for a in run.aside} if run is not None else set()
        for leftover in path.parent.glob(f".{glob.escape(path.name)}.{TMP}*"):
            if leftover.name.endswith((".tmp", ".old")) and _resolve(leftover) not in aside:
                shutil.rmtree(leftover) if leftover.is_dir() else leftover.unlink()
        yield c
    except BaseException as e:
        # a failed write leaves the record as it was
        if c.fd is not None:
            os.ftruncate(c.fd, 0)
            if rec is not None:
                os.pwrite(c.fd, (json.dumps(rec, indent=1, sort_keys=True) + "\n").encode(), 0)
        full = _disk_full(e)
        if full is not None:  # the output's disk, whatever file (an input copied, a library's) the error named
            raise OSError(full, os.strerror(full), str(path)) from None
        raise
    finally:
        os.close(fd)  # closing releases the lock
        c.fd = None
        if created and not _read_record(rec_path):
            rec_path.unlink(missing_ok=True)  # a refused or failed first write leaves no record
            if not os.path.lexists(path):
                for folder in made:  # nor the folders made for it
                    with contextlib.suppress(OSError):
                        folder.rmdir()
