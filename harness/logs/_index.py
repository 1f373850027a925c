"""Find what an MCAP file holds: from its summary section if it was finished, else by a recovery scan.

A cleanly finished file is indexed from its summary (schemas, channels, statistics, chunk and
metadata indexes) without reading the data. A file without a valid footer and summary (a killed
writer, a cut copy) is scanned record by record from the start, one record in memory at a time:
every complete chunk whose CRC matches is kept, a chunk that fails is skipped with a message
naming its offset, and the scan stops at the first record that is cut off or unreadable, saying
how many bytes (and, where the cut chunk's header survived, how many seconds) were lost.

Every length read from the file is bounded before it is used: a record's length by the file size
(and, for an indexed chunk, by the index), a chunk's uncompressed size by :data:`MAX_CHUNK_BYTES`,
and decompression stops at the declared size. A damaged header therefore makes its chunk
unreadable (skipped, named by offset), never an ``OverflowError`` or a huge allocation.
"""

from __future__ import annotations

import io
import os
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import lz4.frame
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Attachment, Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk

from harness.logs._mcap_writer import MCAP_MAGIC
from harness.logs.topics import LogError

__all__ = ["ChunkInfo", "FileIndex", "RecoveryReport", "build_index", "scan", "load_chunk", "chunk_records", "summary_start",
           "DECODE_ERRORS", "MAX_CHUNK_BYTES"]

#: what a damaged chunk can raise while being decompressed or parsed
DECODE_ERRORS = (McapError, ValueError, RuntimeError, struct.error, EOFError, UnicodeDecodeError, KeyError, MemoryError,
                 OverflowError, zstandard.ZstdError)  # lz4 raises RuntimeError
#: largest uncompressed chunk we read (ours are 1 MiB state / 8 MiB image chunks plus one message)
MAX_CHUNK_BYTES = 1 << 30
_KNOWN = {int(o) for o in Opcode}
_FOOTER_LEN = 1 + 8 + 8 + 8 + 4


@dataclass
class ChunkInfo:
    """Where a chunk (or a lone message record) is, and what it covers."""

    offset: int
    length: int
    start_ns: int
    end_ns: int
    compression: str | None  # None: a bare Message record outside any chunk
    channel_ids: set | None = None  # None: unknown without reading the chunk


@dataclass(frozen=True)
class RecoveryReport:
    """How much of an unfinished or damaged file was recovered."""

    reason: str
    recovered_chunks: int
    recovered_messages: int
    good_bytes: int
    lost_bytes: int
    skipped_chunks: tuple  # ((offset, why), ...)
    lost_log_time_s: float | None  # from a cut chunk's header when it survived, else None
    data_complete: bool = False  # the data section ended (DataEnd seen): nothing but summary bytes lost

    @property
    def text(self) -> str:
        parts = [f"{self.reason}; recovered {self.recovered_chunks} complete chunks ({self.recovered_messages} messages)"]
        if self.data_complete:
            parts.append("the data section is complete (no message lost)")
        elif self.lost_bytes:
            parts.append(f"lost the last {self.lost_bytes} bytes after offset {self.good_bytes}, and any messages "
                         "the writer had not yet flushed")
        if self.lost_log_time_s is not None:
            parts.append(f"the cut chunk held {self.lost_log_time_s:.3f} s of log time")
        if self.skipped_chunks:
            parts.append(f"skipped {len(self.skipped_chunks)} damaged chunks at offsets "
                         + ", ".join(str(o) for o, _ in self.skipped_chunks))
        return "; ".join(parts)


@dataclass
class FileIndex:
    path: Path
    size_bytes: int
    finished: bool
    schemas: dict = field(default_factory=dict)
    channels: dict = field(default_factory=dict)
    chunks: list = field(default_factory=list)
    metadata: dict = field(default_factory=dict)  # name -> {key: str}
    attachments: dict = field(default_factory=dict)  # name -> (offset, length, media_type, data_size)
    counts: dict = field(default_factory=dict)  # channel id -> messages
    start_ns: int = 0
    end_ns: int = 0
    recovery: RecoveryReport | None = None
    problems: list = field(default_factory=list)


def _decompress(chunk: Chunk) -> bytes:
    """The uncompressed records of ``chunk``, never more than it declares (nor :data:`MAX_CHUNK_BYTES`)."""
    want = chunk.uncompressed_size
    if want > MAX_CHUNK_BYTES:
        raise McapError(f"the chunk declares {want} uncompressed bytes, more than the {MAX_CHUNK_BYTES} we read "
                        "(a damaged header)")
    comp = chunk.compression
    if comp == "":
        raw = chunk.data
    elif comp == "zstd":
        parts, n = [], 0
        with zstandard.ZstdDecompressor().stream_reader(chunk.data) as reader:
            while n <= want:
                part = reader.read(min(want + 1 - n, 1 << 20))
                if not part:
                    break
                parts.append(part)
                n += len(part)
        raw = b"".join(parts)
    elif comp == "lz4":
        raw = lz4.frame.LZ4FrameDecompressor().decompress(chunk.data, max_length=want + 1)
    else:
        raise McapError(f"unknown chunk compression {comp[:20]!r}")
    if len(raw) != want:
        raise McapError(f"the chunk holds {len(raw) if len(raw) <= want else 'more than ' + str(want)} uncompressed "
                        f"bytes but declares {want}")
    if chunk.uncompressed_crc and zlib.crc32(raw) != chunk.uncompressed_crc:
        raise McapError(f"CRC mismatch: the chunk's records have CRC {zlib.crc32(raw):#010x}, "
                        f"its header says {chunk.uncompressed_crc:#010x}")
    return raw


def chunk_records(chunk: Chunk) -> list:
    """The records of ``chunk`` (bounded decompression, CRC-checked)."""
    raw = _decompress(chunk)
    return breakup_chunk(Chunk(compression="", data=raw, message_start_time=chunk.message_start_time,
                               message_end_time=chunk.message_end_time, uncompressed_crc=0,
                               uncompressed_size=len(raw)))


def _record_length(f, offset: int, size: int, expected: int | None = None) -> tuple[int, int]:
    """(opcode, length) of the record at ``offset``, the length bounded by the file (and the index)."""
    f.seek(offset)
    head = f.read(9)
    if len(head) < 9:
        raise EOFError(f"record header at offset {offset} is cut off")
    op, length = struct.unpack("<BQ", head)
    if offset + 9 + length > size:
        raise McapError(f"the record at offset {offset} declares {length} bytes, past the end of the "
                        f"{size}-byte file (a damaged header)")
    if expected is not None and 9 + length != expected:
        raise McapError(f"the record at offset {offset} declares {9 + length} bytes, the index {expected} "
                        "(a damaged header)")
    return op, length


def load_chunk(f, info: ChunkInfo, size: int | None = None, *, check_length: bool = True) -> list:
    """Records of one chunk (CRC-checked), or the lone Message at ``info.offset``.

    size : the file's size in bytes (default: found with ``os.fstat``); bounds every length read
    check_length : the record's length must be ``info.length`` (as indexed)
    """
    if size is None:
        size = os.fstat(f.fileno()).st_size
    op, length = _record_length(f, info.offset, size, info.length if check_length else None)
    body = f.read(length)
    if len(body) < length:
        raise EOFError(f"record at offset {info.offset} is cut off")
    stream = ReadDataStream(io.BytesIO(body))
    if info.compression is None:
        return [Message.read(stream, length)]
    if op != Opcode.CHUNK:
        raise McapError(f"expected a chunk at offset {info.offset}, found opcode {op:#04x}")
    return chunk_records(Chunk.read(stream))


def build_index(path) -> FileIndex:
    """Index ``path``; raises :class:`LogError` when it is not an MCAP file at all."""
    path = Path(path)
    try:
        size = path.stat().st_size
        f = open(path, "rb")
    except OSError as exc:
        raise LogError(f"cannot open log {str(path)!r}: {exc.strerror}") from None
    with f:
        magic = f.read(8)
        if magic != MCAP_MAGIC:
            what = "is empty" if size == 0 else f"starts with {magic[:8]!r}, not the MCAP magic"
            raise LogError(f"{path} is not an MCAP file: it {what}")
        reason = _summary_problem(f, size)
        if reason is None:
            try:
                return _from_summary(f, path, size)
            except DECODE_ERRORS as exc:
                reason = f"the summary section is unreadable ({exc})"
        return scan(f, path, size, reason)


def _read_footer(f, size: int) -> bytes:
    """The footer record (opcode, length, summary start, summary offset start, crc) before the closing magic."""
    f.seek(size - 8 - _FOOTER_LEN)
    return f.read(_FOOTER_LEN)


def summary_start(f, size: int) -> int:
    """Where a finished file's summary section starts (its data section ends), from the footer."""
    return struct.unpack("<BQQQI", _read_footer(f, size))[2]


def _summary_problem(f, size: int) -> str | None:
    """Why the footer/summary cannot be trusted, or None if it can."""
    if size < 8 + _FOOTER_LEN + 8:
        return "the file is too short to hold a footer (the writer was killed or the file was cut)"
    f.seek(size - 8)
    if f.read(8) != MCAP_MAGIC:
        return "no footer (the writer was killed or the file was cut)"
    raw = _read_footer(f, size)
    op, length, summary_start, offset_start, crc = struct.unpack("<BQQQI", raw)
    if op != Opcode.FOOTER or length != 20 or summary_start == 0 or summary_start >= size:
        return "no usable summary section (footer without a summary)"
    if crc:
        f.seek(summary_start)
        got = zlib.crc32(f.read(size - 8 - _FOOTER_LEN - summary_start))
        got = zlib.crc32(raw[:-4], got)
        if got != crc:
            return "the summary section is damaged (CRC mismatch)"
    return None


def _from_summary(f, path: Path, size: int) -> FileIndex:
    f.seek(0)
    reader = SeekingReader(f)
    summary = reader.get_summary()
    idx = FileIndex(path=path, size_bytes=size, finished=True, schemas=dict(summary.schemas),
                    channels=dict(summary.channels))
    st = summary.statistics
    if st is not None:
        idx.counts = dict(st.channel_message_counts)
        idx.start_ns, idx.end_ns = st.message_start_time, st.message_end_time
    if st is not None and st.message_count and not summary.chunk_indexes:
        raise McapError("messages but no chunk index")
    idx.chunks = [ChunkInfo(ci.chunk_start_offset, ci.chunk_length, ci.message_start_time, ci.message_end_time,
                            ci.compression, set(ci.message_index_offsets) or None) for ci in summary.chunk_indexes]
    for m in reader.iter_metadata():
        idx.metadata[m.name] = dict(m.metadata)
    for a in summary.attachment_indexes:
        idx.attachments[a.name] = (a.offset, a.length, a.media_type, a.data_size)
    return idx


def _plausible_chunk_header(h: bytes, offset: int, size: int) -> bool:
    """Do the first bytes ``h`` at ``offset`` read as a Chunk record header whose lengths all agree?"""
    if len(h) < 53 or h[0] != Opcode.CHUNK:
        return False
    length = struct.unpack_from("<Q", h, 1)[0]
    t0, t1, usize, _, clen = struct.unpack_from("<QQQII", h, 9)
    if offset + 9 + length > size or t1 < t0 or usize > MAX_CHUNK_BYTES or clen not in (0, 3, 4):
        return False
    if h[41:41 + clen] not in (b"", b"lz4", b"zstd"):
        return False
    data_len = struct.unpack_from("<Q", h, 41 + clen)[0]
    return 8 + 8 + 8 + 4 + 4 + clen + 8 + data_len == length


def _next_chunk(f, start: int, size: int) -> int | None:
    """Offset of the first chunk record after ``start`` that is whole and intact (CRC), or None.

    Used to resynchronise after a damaged record header; a candidate must have a consistent header
    and pass the CRC of its records, so a false match is practically impossible.
    """
    block = 1 << 20
    pos = start
    while pos < size:
        f.seek(pos)
        buf = f.read(block + 64)
        i = buf.find(b"\x06")
        while 0 <= i < block:
            cand = pos + i
            if _plausible_chunk_header(buf[i:i + 64], cand, size):
                try:
                    load_chunk(f, ChunkInfo(cand, 0, 0, 0, "?"), size, check_length=False)
                    return cand
                except DECODE_ERRORS:
                    pass
            i = buf.find(b"\x06", i + 1)
        pos += block
    return None


def scan(f, path: Path, size: int, reason: str) -> FileIndex:
    """Read every record from the start; keep what is complete and intact (see the module doc)."""
    idx = FileIndex(path=Path(path), size_bytes=size, finished=False)
    skipped, lost_time, pos, footer, data_end = [], None, 8, False, False
    n_msgs, t_min, t_max = 0, None, None

    def note_message(channel_id, t):
        nonlocal n_msgs, t_min, t_max
        idx.counts[channel_id] = idx.counts.get(channel_id, 0) + 1
        t_min = t if t_min is None else min(t_min, t)
        t_max = t if t_max is None else max(t_max, t)
        n_msgs += 1

    while pos < size:
        f.seek(pos)
        head = f.read(9)
        if len(head) < 9:
            break
        op, length = struct.unpack("<BQ", head)
        end = pos + 9 + length
        if op not in _KNOWN or end > size:
            nxt = _next_chunk(f, pos + 1, size)
            if nxt is not None:  # damage, not a cut: carry on at the next intact chunk
                why = f"opcode {op:#04x}" if op not in _KNOWN else f"its length {length} runs past the end of the file"
                skipped.append((pos, f"unreadable record header ({why})"))
                idx.problems.append(f"damaged record at offset {pos} skipped ({why}): {nxt - pos} bytes skipped "
                                    f"up to the next intact chunk at offset {nxt}")
                pos = nxt
                continue
        if op not in _KNOWN:
            idx.problems.append(f"unreadable record at offset {pos} (opcode {op:#04x}); the rest of the file "
                                f"({size - pos} bytes) cannot be read")
            break
        if end > size:
            if op == Opcode.CHUNK and size - pos >= 9 + 16:
                f.seek(pos + 9)
                t0, t1 = struct.unpack("<QQ", f.read(16))
                if t1 >= t0:
                    lost_time = (t1 - t0) * 1e-9
            break
        body = f.read(length)
        stream = ReadDataStream(io.BytesIO(body))
        try:
            if op == Opcode.SCHEMA:
                s = Schema.read(stream)
                idx.schemas[s.id] = s
            elif op == Opcode.CHANNEL:
                c = Channel.read(stream)
                idx.channels[c.id] = c
            elif op == Opcode.METADATA:
                m = Metadata.read(stream)
                idx.metadata[m.name] = dict(m.metadata)
            elif op == Opcode.ATTACHMENT:
                a = Attachment.read(stream)
                idx.attachments[a.name] = (pos, end - pos, a.media_type, len(a.data))
            elif op == Opcode.MESSAGE:
                m = Message.read(stream, length)
                idx.chunks.append(ChunkInfo(pos, end - pos, m.log_time, m.log_time, None, {m.channel_id}))
                note_message(m.channel_id, m.log_time)
            elif op == Opcode.CHUNK:
                chunk = Chunk.read(stream)
                records = chunk_records(chunk)
                ids = set()
                for r in records:
                    if isinstance(r, Message):
                        ids.add(r.channel_id)
                        note_message(r.channel_id, r.log_time)
                    elif isinstance(r, Schema):
                        idx.schemas[r.id] = r
                    elif isinstance(r, Channel):
                        idx.channels[r.id] = r
                idx.chunks.append(ChunkInfo(pos, end - pos, chunk.message_start_time, chunk.message_end_time,
                                            chunk.compression, ids))
            elif op == Opcode.DATA_END:
                data_end = True
            elif op == Opcode.FOOTER:
                footer = True
                pos = end
                break
        except DECODE_ERRORS as exc:
            what = "chunk" if op == Opcode.CHUNK else Opcode(op).name.lower() + " record"
            skipped.append((pos, f"{type(exc).__name__}: {exc}"))
            idx.problems.append(f"damaged {what} at offset {pos} skipped ({type(exc).__name__}: {exc})")
        pos = end
    if n_msgs:
        idx.start_ns, idx.end_ns = t_min, t_max
    good = min(pos, size)
    lost = 0 if footer else size - good
    idx.recovery = RecoveryReport(reason=reason, recovered_chunks=sum(c.compression is not None for c in idx.chunks),
                                  recovered_messages=n_msgs, good_bytes=good, lost_bytes=lost,
                                  skipped_chunks=tuple(skipped), lost_log_time_s=lost_time,
                                  data_complete=data_end and not skipped)
    return idx
