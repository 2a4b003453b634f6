"""A checkpoint with a flipped bit in any of its tensors is refused by its CRC, never loaded
as other weights and scored."""

from __future__ import annotations

import struct
import zipfile

import pytest

from nanosysid.errors import DataError
from nanosysid.models.learned import build_model, load_checkpoint, save_checkpoint

CLASS = "silent acceptance"

NETWORK = {"name": "mlp", "options": {"hidden": [16, 16]}}


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    path = tmp_path_factory.mktemp("ckpt") / "m.pt"
    save_checkpoint(build_model(NETWORK, None), NETWORK, path)
    return path


def data_offsets(path):
    """(entry name, offset of its first data byte, size) of every tensor entry of a torch zip."""
    out = []
    raw = path.read_bytes()
    with zipfile.ZipFile(path) as z:
        for info in z.infolist():
            if "/data/" not in info.filename or info.file_size == 0:
                continue
            n, m = struct.unpack("<HH", raw[info.header_offset + 26: info.header_offset + 30])
            out.append((info.filename, info.header_offset + 30 + n + m, info.file_size))
    return out


@pytest.mark.parametrize("where", ["first byte", "middle", "last byte"])
@pytest.mark.parametrize("entry", range(4))
def test_a_flipped_bit_in_a_tensor_is_refused(checkpoint, tmp_path, entry, where):
    entries = data_offsets(checkpoint)
    assert len(entries) >= 4
    name, start, size = entries[entry]
    at = start + {"first byte": 0, "middle": size // 2, "last byte": size - 1}[where]
    raw = bytearray(checkpoint.read_bytes())
    raw[at] ^= 0x10
    bad = tmp_path / "flipped.pt"
    bad.write_bytes(bytes(raw))
    with pytest.raises(DataError, match=rf"flipped\.pt: the checkpoint is damaged \(entry '{name}' fails its CRC"):
        load_checkpoint(bad)
    load_checkpoint(checkpoint)  # the intact one loads


def test_a_diverged_or_empty_training_writes_no_model(tmp_path):
    import functools

    import torch

    from nanosysid.errors import ConfigError
    from nanosysid.models.training import train_model
    from nanosysid.synthetic import synthetic_flights

    flights = synthetic_flights([f"square_20250101_run{k}" for k in (1, 2)], 120, seed=3)
    quick = dict(horizon=5, stride=5, epochs=3, patience=5, batch_size=64, val_runs=[2], seed=0, progress=False)
    out = tmp_path / "m.pt"
    with pytest.raises(ConfigError, match=r"training diverged .* optimizer\.lr, now 1000000\.0"):
        train_model(NETWORK, flights, out, optimizer=functools.partial(torch.optim.SGD, lr=1e6), **quick)
    with pytest.raises(ConfigError, match=r"network 'mlp': options .* no weights; every layer needs a width of at least 1"):
        train_model({"name": "mlp", "options": {"hidden": [0]}}, flights, out, **quick)
    assert not out.exists()


def _resaved(checkpoint, tmp_path, edit):
    """The checkpoint loaded, changed by ``edit(payload)`` and saved again by torch (zip CRCs new)."""
    import torch

    payload = torch.load(checkpoint, weights_only=True)
    edit(payload)
    out = tmp_path / "resaved.pt"
    torch.save(payload, out)
    return out


def _nudge_weight(p):
    name = next(k for k in p["state_dict"] if k.endswith("weight"))
    p["state_dict"][name] = p["state_dict"][name].clone()
    p["state_dict"][name].view(-1)[0] += 1e-6


EDITS = [
    ("one weight nudged by 1e-6", _nudge_weight, "differ from those the checkpoint was written with"),
    ("a bias zeroed", lambda p: p["state_dict"].__setitem__(
        next(k for k in p["state_dict"] if k.endswith("bias")), 0 * next(v for k, v in p["state_dict"].items() if k.endswith("bias"))),
     "differ from those the checkpoint was written with"),
    ("the normalisation's scale changed", lambda p: p["state_dict"].__setitem__(
        next(k for k in p["state_dict"] if "scale" in k or "std" in k),
        2 * next(v for k, v in p["state_dict"].items() if "scale" in k or "std" in k)),
     "differ from those the checkpoint was written with"),
    ("the physics spec edited", lambda p: p.__setitem__("physics", {"vehicle": {}, "dt": 0.01, "substeps": 1,
                                                                     "angular_dynamics": False}),
     "differ from those the checkpoint was written with"),
    ("the content hash removed", lambda p: p.pop("sha256"), "field 'sha256' is missing"),
]


@pytest.mark.parametrize("case,edit,words", EDITS, ids=[e[0] for e in EDITS])
def test_weights_changed_after_training_are_refused_by_the_content_hash(checkpoint, tmp_path, case, edit, words):
    bad = _resaved(checkpoint, tmp_path, edit)
    with pytest.raises(DataError, match="resaved.pt: ") as e:
        load_checkpoint(bad)
    assert words in str(e.value), str(e.value)


def test_a_checkpoint_in_torchs_older_format_is_named_so_not_damaged(checkpoint, tmp_path):
    import torch

    from nanosysid.errors import DataError
    from nanosysid.models.learned import load_checkpoint

    legacy = tmp_path / "legacy.pt"
    torch.save(torch.load(checkpoint, weights_only=True), legacy, _use_new_zipfile_serialization=False)
    with pytest.raises(DataError, match=r"legacy.pt: a checkpoint in torch's older format .* save it again"):
        load_checkpoint(legacy)
