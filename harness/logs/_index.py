"""Find what an MCAP file holds: from its summary section if it was finished, else by a recovery scan.

A cleanly finished file is indexed from its summary (schemas, channels, statistics, chunk and
metadata indexes) without reading the data. A file without a valid footer and summary (a killed
writer, a cut copy) is scanned record by record from the start, one record in memory at a time:
every complete chunk whose CRC matches is kept, a chunk that fails is skipped with a message
naming its offset, and the scan stops at the first record that is cut off or unreadable, saying
how many bytes (and, where the cut chunk's header survived, how many seconds) were lost.
"""

from __future__ import annotations

import io
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Attachment, Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk

from harness.logs._mcap_writer import MCAP_MAGIC
from harness.logs.topics import LogError

__all__ = ["ChunkInfo", "FileIndex", "RecoveryReport", "build_index", "scan", "load_chunk", "DECODE_ERRORS"]

#: what a damaged chunk can raise while being decompressed or parsed
DECODE_ERRORS = (McapError, ValueError, RuntimeError, struct.error, EOFError, UnicodeDecodeError, KeyError, MemoryError,
                 zstandard.ZstdError)  # lz4 raises RuntimeError
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


def load_chunk(f, info: ChunkInfo) -> list:
    """Records of one chunk (CRC-checked), or the lone Message at ``info.offset``."""
    f.seek(info.offset)
    head = f.read(9)
    if len(head) < 9:
        raise EOFError(f"record header at offset {info.offset} is cut off")
    op, length = struct.unpack("<BQ", head)
    body = f.read(length)
    if len(body) < length:
        raise EOFError(f"record at offset {info.offset} is cut off")
    stream = ReadDataStream(io.BytesIO(body))
    if info.compression is None:
        return [Message.read(stream, length)]
    if op != Opcode.CHUNK:
        raise McapError(f"expected a chunk at offset {info.offset}, found opcode {op:#04x}")
    return breakup_chunk(Chunk.read(stream), validate_crc=True)


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


def _summary_problem(f, size: int) -> str | None:
    """Why the footer/summary cannot be trusted, or None if it can."""
    if size < 8 + _FOOTER_LEN + 8:
        return "the file is too short to hold a footer (the writer was killed or the file was cut)"
    f.seek(size - 8)
    if f.read(8) != MCAP_MAGIC:
        return "no footer (the writer was killed or the file was cut)"
    f.seek(size - 8 - _FOOTER_LEN)
    raw = f.read(_FOOTER_LEN)
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
        if op not in _KNOWN:
            idx.problems.append(f"unreadable record at offset {pos} (opcode {op:#04x}); the rest of the file "
                                f"({size - pos} bytes) cannot be read")
            break
        if end > size:
            if op == Opcode.CHUNK and size - pos >= 9 + 16:
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
                records = breakup_chunk(chunk, validate_crc=True)
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
