"""An MCAP writer with chunk *lanes*: each lane has its own chunk compression and chunk size.

The ``mcap`` package's ``Writer`` has one chunk builder and one compression per file. A session
log wants zstd for the small state messages and no (or lz4) compression for the images, in one
file. MCAP allows that, since compression is a property of each Chunk record, so this writer
keeps one open chunk per lane and builds the records with the package's own record classes
(``mcap.records``): Header, Schema, Channel, Chunk, MessageIndex, Metadata, Attachment, and the
summary section (schemas, channels, statistics, chunk/attachment/metadata indexes, summary
offsets, footer) laid out as ``mcap.writer.Writer.finish`` does, so any MCAP reader (the plain
``mcap`` reader, Foxglove, Lichtblick) opens the file.

Crash safety: schemas, channels, metadata and attachments go straight to the data section (never
inside a chunk), so every complete chunk on disk is decodable even without the summary. A lane's
chunk is closed and handed to the operating system when it exceeds its size, or when its oldest
message is ``flush_period_s`` old in log time or in wall-clock time, whichever comes first. The
log-time rule and the size rule are checked on every message; the wall-clock rule also by a timer
thread (``flush_timer=True``) that wakes every ``flush_period_s / 4`` and closes chunks whose
oldest message is ``3/4 flush_period_s`` old, so a message handed over is on its way to the disk
within ``flush_period_s`` even when no other message follows: a killed process loses at most the
messages of the last ``flush_period_s`` of wall-clock time. All methods are thread-safe (one lock).
"""

from __future__ import annotations

import struct
import threading
import time
import weakref
import zlib
from dataclasses import dataclass
from typing import BinaryIO

import lz4.frame
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Message,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

__all__ = ["LaneSpec", "LaneWriter", "MCAP_MAGIC", "COMPRESSIONS"]

MCAP_MAGIC = b"\x89MCAP0\r\n"
#: chunk compressions understood by every MCAP reader ("" = none)
COMPRESSIONS = ("", "lz4", "zstd")


@dataclass(frozen=True)
class LaneSpec:
    """How one lane chunks its messages.

    compression : ``""`` (none), ``"lz4"`` or ``"zstd"``
    chunk_size_bytes : a chunk is closed once its uncompressed records exceed this size
    """

    compression: str = "zstd"
    chunk_size_bytes: int = 1 << 20

    def __post_init__(self):
        if self.compression not in COMPRESSIONS:
            raise ValueError(f"lane compression must be one of {COMPRESSIONS}, got {self.compression!r}")
        if not (isinstance(self.chunk_size_bytes, int) and self.chunk_size_bytes > 0):
            raise ValueError(f"chunk_size_bytes must be a positive int, got {self.chunk_size_bytes!r}")


class _Lane:
    """The open chunk of one lane."""

    def __init__(self, spec: LaneSpec):
        self.spec = spec
        self.records = RecordBuilder()
        self.indices: dict[int, MessageIndex] = {}
        self.n_messages = 0
        self.start_ns = 0
        self.end_ns = 0
        self.opened_wall_s = 0.0

    def add(self, message: Message) -> None:
        if self.n_messages == 0:
            self.start_ns = self.end_ns = message.log_time
            self.opened_wall_s = time.monotonic()
        else:
            self.start_ns = min(self.start_ns, message.log_time)
            self.end_ns = max(self.end_ns, message.log_time)
        idx = self.indices.get(message.channel_id)
        if idx is None:
            idx = self.indices[message.channel_id] = MessageIndex(channel_id=message.channel_id, records=[])
        idx.records.append((message.log_time, self.records.count))
        message.write(self.records)
        self.n_messages += 1


class LaneWriter:
    """Chunked MCAP writer with one open chunk per named lane.

    stream : a binary stream opened for writing (it is flushed, never closed, by this class)
    lanes : lane name -> :class:`LaneSpec`
    flush_period_s : close a lane's chunk once its oldest message is this old (log or wall time)
    flush_timer : also check the wall-clock age on a timer thread (stopped by :meth:`finish` /
        :meth:`stop_timer`); an error the timer meets writing is raised by the next call
    """

    def __init__(self, stream: BinaryIO, lanes: dict[str, LaneSpec], *, flush_period_s: float = 1.0,
                 profile: str = "", library: str = "rt2", flush_timer: bool = False):
        if not lanes:
            raise ValueError("LaneWriter needs at least one lane")
        self._lock = threading.RLock()
        self._timer_error: BaseException | None = None
        self._stop = threading.Event()
        self._timer: threading.Thread | None = None
        self._stream = stream
        self._lanes = {name: _Lane(spec) for name, spec in lanes.items()}
        self._flush_ns = int(round(flush_period_s * 1e9))
        self._flush_s = float(flush_period_s)
        self._pos = 0
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._chunk_indexes: list[ChunkIndex] = []
        self._attachment_indexes: list[AttachmentIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._stats = Statistics(
            attachment_count=0, channel_count=0, channel_message_counts={}, chunk_count=0,
            message_count=0, message_end_time=0, message_start_time=0, metadata_count=0, schema_count=0,
        )
        self._zstd = zstandard.ZstdCompressor(level=3)
        self._finished = False
        self._write(MCAP_MAGIC)
        self._write_record(Header(profile=profile, library=library))
        self._stream.flush()
        if flush_timer:
            self._timer = threading.Thread(target=_timer_loop, args=(weakref.ref(self), self._stop, self._flush_s / 4),
                                           name="rt2-log-flush", daemon=True)
            self._timer.start()

    # -- the timer ------------------------------------------------------------------------------
    def flush_old(self) -> None:
        """Close every lane chunk whose oldest message is 3/4 of ``flush_period_s`` old in wall time
        (what the timer calls every ``flush_period_s / 4``)."""
        with self._lock:
            if not self._finished:
                self._close_old(None, 0.75 * self._flush_s)

    def stop_timer(self) -> None:
        """Stop the flush timer (if any) and wait for it; safe to call more than once."""
        self._stop.set()
        if self._timer is not None and self._timer is not threading.current_thread():
            self._timer.join()

    def _check_timer(self) -> None:
        if self._timer_error is not None:
            raise OSError(f"the log's flush timer failed: {self._timer_error}") from self._timer_error

    # -- low level ------------------------------------------------------------------------------
    def _write(self, data: bytes) -> None:
        self._stream.write(data)
        self._pos += len(data)

    def _write_record(self, record) -> int:
        """Write one record to the data section; return its offset and length."""
        rb = RecordBuilder()
        record.write(rb)
        offset = self._pos
        self._write(rb.end())
        return offset

    @property
    def bytes_written(self) -> int:
        return self._pos

    # -- definitions (data section, outside chunks) ----------------------------------------------
    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        with self._lock:
            self._check_timer()
            schema = Schema(id=len(self._schemas) + 1, name=name, encoding=encoding, data=data)
            self._schemas[schema.id] = schema
            self._stats.schema_count += 1
            self._write_record(schema)
            return schema.id

    def register_channel(self, topic: str, message_encoding: str, schema_id: int, metadata: dict | None = None) -> int:
        with self._lock:
            self._check_timer()
            channel = Channel(id=len(self._channels) + 1, topic=topic, message_encoding=message_encoding,
                              schema_id=schema_id, metadata=dict(metadata or {}))
            self._channels[channel.id] = channel
            self._stats.channel_count += 1
            self._stats.channel_message_counts[channel.id] = 0
            self._write_record(channel)
            return channel.id

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        with self._lock:
            self._check_timer()
            start = self._pos
            self._write_record(Metadata(name=name, metadata=data))
            self._metadata_indexes.append(MetadataIndex(offset=start, length=self._pos - start, name=name))
            self._stats.metadata_count += 1
            self._stream.flush()

    def add_attachment(self, name: str, media_type: str, data: bytes, log_time_ns: int, create_time_ns: int = 0) -> None:
        with self._lock:
            self._check_timer()
            start = self._pos
            self._write_record(Attachment(create_time=create_time_ns, log_time=log_time_ns, name=name,
                                          media_type=media_type, data=data))
            self._attachment_indexes.append(AttachmentIndex(
                offset=start, length=self._pos - start, log_time=log_time_ns, create_time=create_time_ns,
                data_size=len(data), name=name, media_type=media_type))
            self._stats.attachment_count += 1
            self._stream.flush()

    # -- messages -------------------------------------------------------------------------------
    def add_message(self, lane: str, channel_id: int, log_time_ns: int, data: bytes, sequence: int = 0) -> None:
        """Append a message to ``lane``'s open chunk (closing chunks that are full or old)."""
        with self._lock:
            self._check_timer()
            self._add_message(lane, channel_id, log_time_ns, data, sequence)

    def _add_message(self, lane: str, channel_id: int, log_time_ns: int, data: bytes, sequence: int) -> None:
        st = self._stats
        if st.message_count == 0:
            st.message_start_time = st.message_end_time = log_time_ns
        else:
            st.message_start_time = min(st.message_start_time, log_time_ns)
            st.message_end_time = max(st.message_end_time, log_time_ns)
        st.message_count += 1
        st.channel_message_counts[channel_id] += 1
        ln = self._lanes[lane]
        ln.add(Message(channel_id=channel_id, log_time=log_time_ns, data=data, publish_time=log_time_ns,
                       sequence=sequence & 0xFFFFFFFF))
        if ln.records.count > ln.spec.chunk_size_bytes:
            self._close_chunk(ln)
            self._stream.flush()
        self._flush_due(log_time_ns)

    def flush_due(self, now_log_ns: int) -> None:
        """Close every lane chunk whose oldest message is ``flush_period_s`` old (log or wall time)."""
        with self._lock:
            self._flush_due(now_log_ns)

    def _flush_due(self, now_log_ns: int) -> None:
        self._close_old(now_log_ns, self._flush_s)

    def _close_old(self, now_log_ns: int | None, wall_age_s: float) -> None:
        """Close the lane chunks ``flush_period_s`` old in log time (None: not checked) or ``wall_age_s`` in wall time."""
        wall = time.monotonic()
        closed = False
        for ln in self._lanes.values():
            if ln.n_messages and ((now_log_ns is not None and now_log_ns - ln.start_ns >= self._flush_ns)
                                  or wall - ln.opened_wall_s >= wall_age_s):
                self._close_chunk(ln)
                closed = True
        if closed:
            self._stream.flush()

    def flush(self) -> None:
        """Close every open chunk and hand all bytes to the operating system."""
        with self._lock:
            self._check_timer()
            for ln in self._lanes.values():
                self._close_chunk(ln)
            self._stream.flush()

    def _close_chunk(self, ln: _Lane) -> None:
        if ln.n_messages == 0:
            return
        raw = ln.records.end()
        comp = ln.spec.compression
        if comp == "zstd":
            data = self._zstd.compress(raw)
        elif comp == "lz4":
            data = lz4.frame.compress(raw)
        else:
            data = raw
        chunk = Chunk(compression=comp, data=data, message_start_time=ln.start_ns, message_end_time=ln.end_ns,
                      uncompressed_crc=zlib.crc32(raw), uncompressed_size=len(raw))
        chunk_start = self._pos
        self._write_record(chunk)
        chunk_length = self._pos - chunk_start
        index_start = self._pos
        offsets = {}
        rb = RecordBuilder()
        for channel_id, idx in ln.indices.items():
            offsets[channel_id] = index_start + rb.count
            idx.write(rb)
        self._write(rb.end())
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=ln.start_ns, message_end_time=ln.end_ns, chunk_start_offset=chunk_start,
            chunk_length=chunk_length, message_index_offsets=offsets, message_index_length=self._pos - index_start,
            compression=comp, compressed_size=len(data), uncompressed_size=len(raw)))
        self._stats.chunk_count += 1
        ln.indices = {}
        ln.n_messages = 0

    # -- summary --------------------------------------------------------------------------------
    def finish(self) -> None:
        """Close all chunks, write the summary section and footer (see the MCAP spec); stops the timer."""
        self.stop_timer()
        with self._lock:
            self._finish()

    def _finish(self) -> None:
        if self._finished:
            return
        for ln in self._lanes.values():
            self._close_chunk(ln)
        self._write_record(DataEnd(data_section_crc=0))
        summary_start = self._pos
        rb = RecordBuilder()
        offsets: list[SummaryOffset] = []

        def group(opcode, records):
            begin = rb.count
            for r in records:
                r.write(rb)
            if rb.count > begin:
                offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + begin,
                                             group_length=rb.count - begin))

        group(Opcode.SCHEMA, self._schemas.values())
        group(Opcode.CHANNEL, self._channels.values())
        group(Opcode.STATISTICS, [self._stats])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.ATTACHMENT_INDEX, self._attachment_indexes)
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        summary_offset_start = summary_start + rb.count
        for off in offsets:
            off.write(rb)
        summary = rb.end()
        # Footer CRC covers the summary section and the footer's fields before the CRC (MCAP spec).
        crc = zlib.crc32(summary)
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 8 + 8 + 4, summary_start, summary_offset_start), crc)
        self._write(summary)
        self._write_record(Footer(summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=crc))
        self._write(MCAP_MAGIC)
        self._stream.flush()
        self._finished = True


def _timer_loop(ref, stop: threading.Event, period_s: float) -> None:
    """Body of the flush timer: holds the writer only weakly, so an abandoned writer is not kept alive."""
    while not stop.wait(period_s):
        writer = ref()
        if writer is None:
            return
        try:
            writer.flush_old()
        except BaseException as exc:  # raised again by the writer's next call, in the caller's thread
            writer._timer_error = exc
            return
        finally:
            del writer
