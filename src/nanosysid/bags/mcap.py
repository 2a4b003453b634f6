"""The few parts of the MCAP format (https://mcap.dev/spec) that the rosbags writer and reader
leave unchecked: chunk CRCs (written as zero, "not computed") and the message indexes, which
carry no CRC of their own and which the reader follows to every message."""

from __future__ import annotations

import zlib
from pathlib import Path
from typing import Iterator

try:  # the zstd module of Python >= 3.14, or its backport (a dependency of rosbags)
    from compression import zstd
except ImportError:
    from backports import zstd

__all__ = ["MAGIC", "set_chunk_crcs", "check_indexes"]

MAGIC = b"\x89MCAP0\r\n"
_FOOTER, _MESSAGE, _CHUNK, _MESSAGE_INDEX = 0x02, 0x05, 0x06, 0x07


def _u(data, at: int, size: int) -> int:
    return int.from_bytes(data[at:at + size], "little")


def _records(data) -> Iterator[tuple[int, int, int]]:
    """(opcode, start of the body, length of the body) of each top-level record, to the footer."""
    pos = len(MAGIC)
    while pos + 9 <= len(data):
        op, length = data[pos], _u(data, pos + 1, 8)
        if pos + 9 + length > len(data):
            raise ValueError(f"record at byte {pos} runs past the end of the file")
        yield op, pos + 9, length
        if op == _FOOTER:
            return
        pos += 9 + length


def _chunk(data, body: int) -> tuple[int, bytes]:
    """(the byte of the CRC field, the uncompressed records) of a chunk record."""
    size = _u(data, body + 16, 8)
    n_name = _u(data, body + 28, 4)
    compression = bytes(data[body + 32:body + 32 + n_name]).decode()
    at = body + 32 + n_name
    packed = bytes(data[at + 8:at + 8 + _u(data, at, 8)])
    if compression not in ("zstd", ""):
        raise ValueError(f"chunk compression {compression!r} is not read here")
    raw = zstd.decompress(packed) if compression == "zstd" else packed
    if len(raw) != size:
        raise ValueError(f"a chunk holds {len(raw)} bytes, its header says {size}")
    return body + 24, raw


def set_chunk_crcs(path: Path) -> None:
    """Fill in the CRC-32 of every chunk's uncompressed records (the writer leaves them at
    zero): every MCAP reader then checks each chunk it reads."""
    data = bytearray(Path(path).read_bytes())
    if data[:len(MAGIC)] != MAGIC:
        return
    for op, body, _ in list(_records(data)):
        if op == _CHUNK:
            at, raw = _chunk(data, body)
            data[at:at + 4] = zlib.crc32(raw).to_bytes(4, "little")
    Path(path).write_bytes(bytes(data))


def check_indexes(path: Path) -> str | None:
    """The first message index entry of an MCAP file that does not point at a message of its
    channel and time in the chunk before it, described; None when every entry does."""
    data = Path(path).read_bytes()
    if data[:len(MAGIC)] != MAGIC:
        return None
    try:
        raw = b""
        for op, body, length in _records(data):
            if op == _CHUNK:
                raw = _chunk(data, body)[1]
            elif op == _MESSAGE_INDEX:
                channel = _u(data, body, 2)
                n = _u(data, body + 2, 4)
                for k in range(body + 6, body + 6 + n, 16):
                    time, offset = _u(data, k, 8), _u(data, k + 8, 8)
                    if (offset + 9 + 22 > len(raw) or raw[offset] != _MESSAGE or _u(raw, offset + 9, 2) != channel
                            or _u(raw, offset + 15, 8) != time):
                        return (f"the message index at byte {body - 9} points at byte {offset} of its chunk, "
                                f"where no message of channel {channel} logged at {time} ns is")
    except (ValueError, IndexError, zstd.ZstdError) as e:
        return f"{type(e).__name__}: {e}"
    return None
