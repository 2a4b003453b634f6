"""Byte-stable RRD files: the same recording written twice, on any machine, gives the same bytes.

The rerun SDK stamps every store, chunk and row with a time-based unique id (a TUID: the
wall-clock nanoseconds and a random counter), names the blueprint's store with a random id and
gives blueprint rows a ``log_time`` timeline of wall-clock time. :func:`canonical` rewrites an RRD
stream so that none of this remains, and drops its footer (which indexes the chunks by those ids
and byte offsets); :func:`with_footer` writes the footer anew:

- every TUID becomes the next of a counter, in stream order (a chunk's id, then its rows'), which
  keeps the rows of every chunk in the order they were logged;
- the blueprint store's id becomes a name derived from the recording's id;
- ``log_time`` cells become zero (the blueprint is placed by its own ``blueprint`` timeline).

The data, the entity paths and the index timelines are left as they are. The stream layout
(``crates/store/re_log_encoding`` in rerun): a 12-byte header (``RRF2``, version, options), then
messages of a little-endian ``u64`` kind and ``u64`` length and a protobuf body
(``rerun.log_msg.v1alpha1``): kind 1 ``SetStoreInfo``, 2 ``ArrowMsg`` (an Arrow IPC stream,
LZ4-compressed when ``compression`` is 2), 3 ``BlueprintActivationCommand``; kind 0 ends it.
"""

from __future__ import annotations

import hashlib
import re
import struct
import subprocess
import sys
import tempfile
from pathlib import Path

import lz4.block
import pyarrow as pa
import xxhash

from nanosysid.errors import DataError

__all__ = ["canonical", "with_footer", "check"]

_END, _SET_STORE_INFO, _ARROW_MSG = 0, 1, 2  # message kinds
_NONE, _LZ4 = 1, 2  # rerun.common.v1alpha1.Compression
_ROW_ID = "rerun.controls.RowId"
_LOG_TIME = "log_time"
# a blueprint store's random id, as the SDK writes it: "rec_" and 32 hex digits
_RANDOM_STORE = re.compile(rb"rec_[0-9a-f]{32}")


def _varint(buf: bytes, i: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        b = buf[i]
        value |= (b & 0x7F) << shift
        i += 1
        if b < 0x80:
            return value, i
        shift += 7


def _encode_varint(value: int) -> bytes:
    out = bytearray()
    while value >= 0x80:
        out.append((value & 0x7F) | 0x80)
        value >>= 7
    out.append(value)
    return bytes(out)


def _fields(buf: bytes) -> list[tuple[int, int, int | bytes]]:
    """A protobuf message's fields in order: ``(number, wire type, value)``; a value is an int for
    varints and the raw bytes otherwise."""
    fields, i = [], 0
    while i < len(buf):
        key, i = _varint(buf, i)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, i = _varint(buf, i)
        elif wire == 1:
            value, i = buf[i:i + 8], i + 8
        elif wire == 2:
            n, i = _varint(buf, i)
            value, i = buf[i:i + n], i + n
        elif wire == 5:
            value, i = buf[i:i + 4], i + 4
        else:
            raise ValueError(f"RRD message: protobuf wire type {wire} is not used by rerun's messages")
        fields.append((number, wire, value))
    return fields


def _encode(fields: list[tuple[int, int, int | bytes]]) -> bytes:
    out = bytearray()
    for number, wire, value in fields:
        out += _encode_varint(number << 3 | wire)
        if wire == 0:
            out += _encode_varint(value)
        elif wire == 2:
            out += _encode_varint(len(value)) + value
        else:
            out += value
    return bytes(out)


class _Ids:
    """The counter every TUID is replaced by, and the blueprint store's new name."""

    def __init__(self, recording_id: str):
        self.count = 0
        self.store = b"rec_" + hashlib.sha256(recording_id.encode()).hexdigest()[:32].encode()

    def next(self) -> tuple[int, int]:
        self.count += 1
        return self.count, 0  # (nanoseconds, counter) of rerun's Tuid


def _tuid(tuid: tuple[int, int]) -> bytes:
    """A ``rerun.common.v1alpha1.Tuid``: fixed64 time_ns = 1, fixed64 inc = 2."""
    return _encode([(1, 1, struct.pack("<Q", tuid[0])), (2, 1, struct.pack("<Q", tuid[1]))])


def _chunk(payload: bytes, chunk_id: tuple[int, int], ids: _Ids) -> bytes:
    """The Arrow IPC stream of one chunk with its id, row ids and log times replaced."""
    reader = pa.ipc.open_stream(payload)
    table = reader.read_all()
    schema = table.schema
    metadata = dict(schema.metadata or {})
    metadata[b"rerun:id"] = b"chunk_%016X%016x" % chunk_id  # as rerun formats a chunk id
    columns = []
    for field, column in zip(schema, table.columns):
        if field.name == _ROW_ID:
            rows = b"".join(struct.pack(">QQ", *ids.next()) for _ in range(len(column)))
            column = pa.FixedSizeBinaryArray.from_buffers(field.type, len(column), [None, pa.py_buffer(rows)])
        elif field.name == _LOG_TIME:
            column = pa.array([0] * len(column), type=field.type)
        columns.append(column)
    table = pa.Table.from_arrays(columns, schema=schema.with_metadata(metadata))
    sink = pa.BufferOutputStream()
    with pa.ipc.new_stream(sink, table.schema) as writer:
        for batch in table.to_batches():
            writer.write_batch(batch)
    return sink.getvalue().to_pybytes()


def _arrow_msg(body: bytes, ids: _Ids) -> bytes:
    fields = _fields(body)
    values = {number: value for number, _, value in fields}
    compression = values.get(2, _NONE)
    payload = values[5]
    if compression == _LZ4:
        payload = lz4.block.decompress(payload, uncompressed_size=values[3])
    elif compression != _NONE:
        raise ValueError(f"RRD message: compression {compression} is not one rerun writes")
    chunk_id = ids.next()
    payload = _chunk(payload, chunk_id, ids)
    out = []
    for number, wire, value in fields:
        if number == 3:
            value = len(payload)
        elif number == 5:
            value = lz4.block.compress(payload, store_size=False) if compression == _LZ4 else payload
        elif number == 1:  # the store's id: only here is it outside a compressed payload
            value = _RANDOM_STORE.sub(ids.store, value)
        elif number == 6:
            value = _tuid(chunk_id)
        out.append((number, wire, value))
    return _encode(out)


def canonical(data: bytes, recording_id: str) -> bytes:
    """The RRD stream ``data`` with its TUIDs, random store id and wall-clock times made canonical.

    Args:
        data: An RRD file, as ``RecordingStream.save`` writes it.
        recording_id: The recording's id; the blueprint store is named after it.

    Returns:
        The same messages in the same order, with the same data, whose bytes depend on the logged
        data alone; without the footer (:func:`with_footer` adds one).
    """
    if data[:4] != b"RRF2":
        raise DataError("rrd.canonical: data is not an RRD stream (no RRF2 header)")
    try:
        return _canonical(data, recording_id)
    except (struct.error, lz4.block.LZ4BlockError, IndexError, ValueError, pa.ArrowException) as e:
        raise DataError(f"rrd.canonical: data is not a whole RRD stream, cut short or damaged ({type(e).__name__}: "
                        f"{str(e).splitlines()[0] if str(e) else ''})") from None


def _canonical(data: bytes, recording_id: str) -> bytes:
    ids = _Ids(recording_id)
    out, i = [data[:12]], 12
    while i < len(data):
        kind, n = struct.unpack_from("<QQ", data, i)
        if i + 16 + n > len(data):
            raise ValueError(f"a message of {n} bytes at byte {i} runs past the end ({len(data)} bytes)")
        body, i = data[i + 16:i + 16 + n], i + 16 + n
        if kind == _END:  # the end, and the footer that indexes the old ids (with_footer writes it anew)
            break
        if kind == _SET_STORE_INFO:
            body = _encode([(number, wire, _tuid(ids.next()) if number == 1 else value)
                            for number, wire, value in _fields(_RANDOM_STORE.sub(ids.store, body))])
        elif kind == _ARROW_MSG:
            body = _arrow_msg(body, ids)
        else:
            body = _RANDOM_STORE.sub(ids.store, body)
        out.append(struct.pack("<QQ", kind, len(body)) + body)
    else:  # rerun ends every stream it saves with an end message: one without it was cut short
        raise ValueError(f"no end message in {len(data)} bytes")
    return b"".join(out)


# the stream's last 32 bytes: the footer message's offset and size (u64), its checksum (u32: xxh32
# with this seed, "RERUN" in base 26), "RRF2FOOT" and a u32 version
_TRAILER = 32
_FOOTER_SEED = 7850921


def with_footer(data: bytes) -> bytes:
    """The footer-less RRD stream ``data`` with rerun's footer (a manifest of every chunk: ids,
    byte offsets, statistics) added by ``rerun rrd migrate``, in an order that does not vary.

    ``migrate`` writes the stores' manifests, and the columns of each manifest's Sorbet schema, in
    the order of hash maps, which varies from run to run. Neither order carries meaning (rerun
    leaves the manifests' order unspecified and fingerprints a schema, ``sorbet_schema_sha256``,
    with its fields sorted by name): here the manifests are sorted by store id, the fields by name.
    """
    with tempfile.TemporaryDirectory(prefix="nanosysid-rrd-") as tmp:
        path = Path(tmp) / "recording.rrd"
        path.write_bytes(data)
        r = subprocess.run([sys.executable, "-m", "rerun_cli", "rrd", "migrate", str(path)],
                           capture_output=True, text=True)
        if r.returncode != 0:
            raise DataError(f"rrd.with_footer: rerun rrd migrate refused the stream (cut short or damaged?): "
                            f"{r.stderr.strip().splitlines()[-1] if r.stderr.strip() else r.returncode}")
        data = path.read_bytes()
    offset, size = struct.unpack_from("<QQ", data, len(data) - _TRAILER)
    manifests = []
    for number, wire, manifest in _fields(data[offset:offset + size]):
        fields = []
        for n, w, value in _fields(manifest):
            if n == 2:  # rerun.common.v1alpha1.Schema: the Arrow IPC schema in field 1
                (k, kw, ipc), = _fields(value)
                schema = pa.ipc.read_schema(pa.py_buffer(ipc))
                schema = pa.schema(sorted(schema, key=lambda f: f.name), metadata=schema.metadata)
                value = _encode([(k, kw, schema.serialize().to_pybytes())])
            fields.append((n, w, value))
        manifests.append((number, wire, _encode(fields)))
    manifests.sort(key=lambda m: _fields(m[2])[0][2])  # one per store, "in unspecified order": by store id
    footer = _encode(manifests)
    trailer = bytearray(data[len(data) - _TRAILER:])
    struct.pack_into("<QQI", trailer, 0, offset, len(footer), xxhash.xxh32_intdigest(footer, seed=_FOOTER_SEED))
    header = struct.pack("<QQ", 0, len(footer))  # the footer's message: kind 0 (end), its length
    return data[:offset - 16] + header + footer + bytes(trailer)


def check(data: bytes) -> None:
    """Refuse bytes that are not one whole RRD stream with its footer: the header, every message
    whole up to the end message, and the trailer whose footer offset, size and checksum agree.
    (``rerun rrd verify`` accepts a cut or random file.)

    Raises:
        ValueError: naming what is wrong and where.
    """
    if data[:4] != b"RRF2":
        raise ValueError("not an RRD stream (no RRF2 header)")
    if len(data) < 12 + 16 + _TRAILER or data[-12:-4] != b"RRF2FOOT":
        raise ValueError(f"no RRD footer at the end of {len(data)} bytes (a cut file?)")
    i = 12
    while True:
        if i + 16 > len(data):
            raise ValueError(f"message header at byte {i} runs past the end ({len(data)} bytes)")
        kind, n = struct.unpack_from("<QQ", data, i)
        if i + 16 + n > len(data) - _TRAILER:
            raise ValueError(f"message at byte {i} ({n} bytes) runs past the end")
        if kind == _END:
            break
        if kind not in (_SET_STORE_INFO, _ARROW_MSG, 3):
            raise ValueError(f"message at byte {i} of unknown kind {kind}")
        i += 16 + n
    offset, size, checksum = struct.unpack_from("<QQI", data, len(data) - _TRAILER)
    if offset != i + 16 or offset + size != len(data) - _TRAILER:
        raise ValueError(f"the trailer's footer ({offset}, {size} bytes) is not the end message at byte {i}")
    if xxhash.xxh32_intdigest(data[offset:offset + size], seed=_FOOTER_SEED) != checksum:
        raise ValueError("the footer's checksum does not match")
