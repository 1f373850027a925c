"""SessionLogReader: stream a session log back in log-time order, decoded to numpy and tracker types.

Reading never loads the file: chunks are read one at a time and merged by log time, so memory is
bounded by the chunks that overlap in time (one image chunk and one state chunk for our logs).
Unfinished or damaged files are read through the recovery scan of :mod:`harness.logs._index`.
"""

from __future__ import annotations

import fnmatch
import heapq
import json
import math
import struct
import warnings
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

from mcap.records import Message
from mcap_protobuf.decoder import DecoderFactory

from harness.logs import codecs
from harness.logs._index import DECODE_ERRORS, FileIndex, RecoveryReport, build_index, load_chunk, scan, summary_start
from harness.logs.topics import LogError

__all__ = ["MAX_DECODE_WORKERS", "SessionLogReader", "LogMessage", "LogSummary", "TopicStats"]

#: the most image-decoding threads ``SessionLogReader.messages(workers=)`` takes
MAX_DECODE_WORKERS = 64
#: images decoded ahead of the caller per worker thread (memory: ~1 MB per VGA image)
DECODE_AHEAD_PER_WORKER = 4
_IMAGE_SCHEMAS = frozenset({"foxglove.CompressedImage", "foxglove.RawImage"})


@dataclass(frozen=True)
class LogMessage:
    """One message: ``data`` is decoded (see docs/logging.md) unless read with ``decode=False`` (bytes)."""

    topic: str
    schema: str
    log_time_ns: int
    sequence: int  # the frame index for per-frame messages
    data: object

    @property
    def t_s(self) -> float:
        return self.log_time_ns * 1e-9


@dataclass(frozen=True)
class TopicStats:
    schema: str
    message_encoding: str
    count: int


@dataclass(frozen=True)
class LogSummary:
    """What a log holds; ``to_dict()`` is the JSON of ``rt2 log info --json``."""

    path: str
    size_bytes: int
    finished_cleanly: bool
    start_s: float
    end_s: float
    n_messages: int
    n_chunks: int
    chunk_compressions: dict
    topics: dict  # topic -> TopicStats
    session: dict
    environment: dict
    session_end: dict | None
    metadata_names: tuple
    attachments: tuple  # ((name, media_type, size_bytes), ...)
    recovery: RecoveryReport | None = None
    problems: tuple = field(default=())

    @property
    def duration_s(self) -> float:
        return max(self.end_s - self.start_s, 0.0)

    def to_dict(self) -> dict:
        d = {k: getattr(self, k) for k in ("path", "size_bytes", "finished_cleanly", "start_s", "end_s", "n_messages",
                                           "n_chunks", "chunk_compressions", "session", "environment", "session_end")}
        d["duration_s"] = self.duration_s
        d["topics"] = {t: {"schema": s.schema, "message_encoding": s.message_encoding, "count": s.count,
                           "rate_hz": s.count / self.duration_s if self.duration_s > 0 else None}
                       for t, s in self.topics.items()}
        d["metadata"] = list(self.metadata_names)
        d["attachments"] = [{"name": n, "media_type": m, "size_bytes": s} for n, m, s in self.attachments]
        d["recovery"] = None if self.recovery is None else {
            "reason": self.recovery.reason, "text": self.recovery.text, "recovered_chunks": self.recovery.recovered_chunks,
            "recovered_messages": self.recovery.recovered_messages, "lost_bytes": self.recovery.lost_bytes,
            "lost_log_time_s": self.recovery.lost_log_time_s,
            "skipped_chunks": [{"offset": o, "error": e} for o, e in self.recovery.skipped_chunks]}
        d["problems"] = list(self.problems)
        return d


def _decode_json_value(text: str):
    try:
        return json.loads(text)
    except (ValueError, RecursionError):
        return text  # written by another tool (or nested beyond reason): keep the plain string


class SessionLogReader:
    """Read a session log written by :class:`~harness.logs.SessionLogWriter` (or any MCAP file).

    Opening indexes the file (summary, or recovery scan for an unfinished file) and raises
    :class:`~harness.logs.LogError` only when the file is not MCAP at all. Damage found while
    reading is reported as a ``RuntimeWarning`` and collected in ``problems``; the rest is read.
    """

    def __init__(self, path):
        self.path = Path(path)
        self._index: FileIndex = build_index(self.path)
        self._file = open(self.path, "rb")
        self._protobuf = DecoderFactory()
        self._decoders: dict[int, object] = {}
        self.problems: list[str] = list(self._index.problems)
        for p in self._index.problems:
            warnings.warn(f"{self.path}: {p}", RuntimeWarning, stacklevel=2)

    # -- what is in the file -------------------------------------------------------------------
    @property
    def finished_cleanly(self) -> bool:
        return self._index.finished

    @property
    def data_complete(self) -> bool:
        """True when no message can be missing: finished cleanly, or only the summary was lost."""
        return self._index.finished or (self._index.recovery is not None and self._index.recovery.data_complete)

    @property
    def recovery(self) -> RecoveryReport | None:
        return self._index.recovery

    def topics(self) -> list[str]:
        return sorted({c.topic for c in self._index.channels.values()})

    def metadata(self, name: str) -> dict:
        """Metadata record ``name`` with its values decoded from JSON."""
        try:
            raw = self._index.metadata[name]
        except KeyError:
            raise LogError(f"{self.path}: no metadata record {name!r}; this log has {sorted(self._index.metadata)}") from None
        return {k: _decode_json_value(v) for k, v in raw.items()}

    def attachment(self, name: str) -> bytes:
        """The bytes of attachment ``name`` (CRC-checked)."""
        try:
            offset, length, _, size = self._index.attachments[name]
        except KeyError:
            raise LogError(f"{self.path}: no attachment {name!r}; this log has {sorted(self._index.attachments)}") from None
        if not 9 <= length <= self._index.size_bytes - offset:
            raise LogError(f"{self.path}: attachment {name!r} at offset {offset} is damaged (its length {length} "
                           f"does not fit the {self._index.size_bytes}-byte file)")
        self._file.seek(offset + 9)
        body = self._file.read(length - 9)
        stored = struct.unpack("<I", body[-4:])[0] if len(body) >= 4 else None
        if stored is None or (stored and zlib.crc32(body[:-4]) != stored):
            raise LogError(f"{self.path}: attachment {name!r} at offset {offset} is damaged (CRC mismatch)")
        return bytes(body[-4 - size: -4])

    def rig(self):
        """The ``tracker.Rig`` attached as ``rig.yaml``."""
        from checks.files import MAX_CONFIG_BYTES, parse_yaml_checked
        from tracker.rig import Rig

        source = f"{self.path}: attachment rig.yaml"
        raw = self.attachment("rig.yaml")
        if len(raw) > MAX_CONFIG_BYTES:
            raise LogError(f"{source} is {len(raw)} bytes, more than a rig file may have ({MAX_CONFIG_BYTES})")
        try:
            data = parse_yaml_checked(raw.decode("utf-8"), source)  # a log may be hostile too: no aliases
        except UnicodeDecodeError:
            raise LogError(f"{source} is not UTF-8 text") from None
        except ValueError as exc:  # parse_yaml_checked names the source already
            raise LogError(str(exc)) from None
        return Rig.from_dict(data, source=source)

    def figures(self) -> dict:
        """{name: figures dict} of every ``/figures/<name>`` message (the last one per name)."""
        out = {}
        names = [t for t in self.topics() if t.startswith("/figures/")]
        for m in self.messages(names) if names else ():
            out[m.topic[len("/figures/"):]] = m.data
        return out

    def summary(self) -> LogSummary:
        idx = self._index
        topics = {}
        for cid, ch in sorted(idx.channels.items(), key=lambda kv: kv[1].topic):
            schema = idx.schemas.get(ch.schema_id)
            topics[ch.topic] = TopicStats(schema.name if schema else "", ch.message_encoding, idx.counts.get(cid, 0))
        comps: dict[str, int] = {}
        for c in idx.chunks:
            if c.compression is not None:
                key = c.compression or "none"
                comps[key] = comps.get(key, 0) + 1
        md = {name: self.metadata(name) for name in ("session", "environment", "session_end") if name in idx.metadata}
        return LogSummary(
            path=str(self.path), size_bytes=idx.size_bytes, finished_cleanly=idx.finished,
            start_s=idx.start_ns * 1e-9, end_s=idx.end_ns * 1e-9, n_messages=sum(idx.counts.values()),
            n_chunks=sum(comps.values()), chunk_compressions=comps, topics=topics,
            session=md.get("session", {}), environment=md.get("environment", {}), session_end=md.get("session_end"),
            metadata_names=tuple(sorted(idx.metadata)),
            attachments=tuple((n, a[2], a[3]) for n, a in sorted(idx.attachments.items())),
            recovery=idx.recovery, problems=tuple(self.problems))

    def verify(self) -> list[str]:
        """Read every record and check every chunk's CRC; return the problems found (empty = intact).

        A finished file is checked chunk by chunk from its index (so one damaged chunk does not hide
        the others) and then scanned record by record; an unfinished one is scanned.
        """
        size = self._index.size_bytes
        problems = []
        with open(self.path, "rb") as f:
            if self._index.finished:
                for info in self._index.chunks:
                    try:
                        load_chunk(f, info, size)
                    except DECODE_ERRORS as exc:
                        problems.append(f"damaged chunk at offset {info.offset} skipped ({type(exc).__name__}: {exc})")
                for name in self._index.attachments:
                    try:
                        self.attachment(name)
                    except LogError as exc:
                        problems.append(str(exc).removeprefix(f"{self.path}: "))
            idx = scan(f, self.path, size, "verify")
        rec = idx.recovery
        problems += [p for p in idx.problems if p not in problems]
        if not rec.data_complete and rec.lost_bytes and not (self._index.finished and rec.good_bytes >= self._data_end()):
            problems.append(f"the data section is cut off or unreadable: {rec.lost_bytes} bytes after offset "
                            f"{rec.good_bytes} cannot be read record by record")
        return problems

    def _data_end(self) -> int:
        """Where the data section of a finished file ends (its summary starts)."""
        with open(self.path, "rb") as f:
            return summary_start(f, self._index.size_bytes)

    # -- messages -------------------------------------------------------------------------------
    def _select(self, topics) -> set:
        if topics is None:
            return set(self._index.channels)
        patterns = [topics] if isinstance(topics, str) else list(topics)
        have = {c.topic: cid for cid, c in self._index.channels.items()}
        chosen = set()
        for p in patterns:
            if not isinstance(p, str):
                raise LogError(f"topics must be strings or glob patterns, got {p!r}")
            hits = [cid for t, cid in have.items() if fnmatch.fnmatchcase(t, p)]
            if not hits:
                raise LogError(f"{self.path}: no topic matches {p!r}; topics: {sorted(have)}")
            chosen.update(hits)
        return chosen

    def messages(self, topics=None, start_s: float | None = None, end_s: float | None = None, *,
                 decode: bool = True, workers: int = 0) -> Iterator[LogMessage]:
        """Messages with ``start_s <= t < end_s`` on ``topics`` (names or glob patterns such as
        ``"/camera/*/image"``; None = all), in log-time order (ties in file order).

        workers : images are decoded by this many threads ahead of the reader (OpenCV's JPEG and PNG
            decoders release the interpreter lock, so they run on every core); the messages and their
            order are exactly those of ``workers=0`` (decoding in the caller's thread)
        """
        wanted = self._select(topics)  # validated here, before the first message is asked for
        for name, v in (("start_s", start_s), ("end_s", end_s)):
            if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise LogError(f"{name} must be a finite number of seconds or None, got {v!r}")
        if isinstance(workers, bool) or not isinstance(workers, int) or not 0 <= workers <= MAX_DECODE_WORKERS:
            raise LogError(f"workers must be a whole number in [0, {MAX_DECODE_WORKERS}], got {workers!r}")
        lo = None if start_s is None else int(round(start_s * 1e9))
        hi = None if end_s is None else int(round(end_s * 1e9))
        if decode and workers:
            return self._decoded_ahead(self._merge(wanted, lo, hi), workers)
        return (self._message(msg, decode) for msg in self._merge(wanted, lo, hi))

    def _decoded_ahead(self, raw: Iterator[Message], workers: int) -> Iterator[LogMessage]:
        """``raw`` records decoded in order: images by a pool of ``workers`` threads, at most
        ``DECODE_AHEAD_PER_WORKER * workers`` messages ahead of the caller, the rest in the caller's thread."""
        from collections import deque
        from concurrent.futures import ThreadPoolExecutor

        ahead: deque = deque()  # futures (images) and records (decoded when their turn comes)
        limit = DECODE_AHEAD_PER_WORKER * workers
        pool = ThreadPoolExecutor(workers, thread_name_prefix="log decode")
        try:
            for msg in raw:
                ahead.append(pool.submit(self._message, msg, True) if self._is_image(msg) else msg)
                while ahead and (len(ahead) > limit or isinstance(ahead[0], Message)):
                    first = ahead.popleft()
                    yield self._message(first, True) if isinstance(first, Message) else first.result()
            while ahead:
                first = ahead.popleft()
                yield self._message(first, True) if isinstance(first, Message) else first.result()
        finally:  # the caller stopped early or a decode failed: drop what was asked ahead
            pool.shutdown(wait=True, cancel_futures=True)

    def _is_image(self, msg: Message) -> bool:
        """Whether ``msg`` is an image; its channel's decoder is made here, in the caller's thread (the
        protobuf classes are built once per channel, never by two threads at once)."""
        ch = self._index.channels[msg.channel_id]
        schema = self._index.schemas.get(ch.schema_id)
        if schema is None or schema.name not in _IMAGE_SCHEMAS or ch.message_encoding != "protobuf":
            return False
        self._decoder(ch, schema)
        return True

    def _decoder(self, ch, schema):
        dec = self._decoders.get(ch.id)
        if dec is None:
            dec = self._decoders[ch.id] = self._protobuf.decoder_for("protobuf", schema)
        return dec

    def _merge(self, wanted: set, lo, hi) -> Iterator[Message]:
        chunks = [c for c in self._index.chunks
                  if (c.channel_ids is None or c.channel_ids & wanted)
                  and (lo is None or c.end_ns >= lo) and (hi is None or c.start_ns < hi)]
        chunks.sort(key=lambda c: (c.start_ns, c.offset))
        heap: list = []
        i = 0
        while True:
            # Load every chunk that may hold a message earlier than the earliest one queued.
            while i < len(chunks) and (not heap or chunks[i].start_ns <= heap[0][0]):
                self._push_chunk(heap, chunks[i], i, wanted, lo, hi)
                i += 1
            if not heap:
                return
            t, _, _, msg = heapq.heappop(heap)
            yield msg

    def _push_chunk(self, heap, info, order, wanted, lo, hi) -> None:
        try:
            records = load_chunk(self._file, info, self._index.size_bytes)
        except DECODE_ERRORS as exc:
            text = f"damaged chunk at offset {info.offset} skipped ({type(exc).__name__}: {exc})"
            if text not in self.problems:
                self.problems.append(text)
                warnings.warn(f"{self.path}: {text}", RuntimeWarning, stacklevel=3)
            return
        for k, r in enumerate(records):
            if isinstance(r, Message) and r.channel_id in wanted and (lo is None or r.log_time >= lo) \
                    and (hi is None or r.log_time < hi):
                heapq.heappush(heap, (r.log_time, order, k, r))

    def _message(self, msg: Message, decode: bool) -> LogMessage:
        ch = self._index.channels[msg.channel_id]
        schema = self._index.schemas.get(ch.schema_id)
        name = schema.name if schema else ""
        data = msg.data
        if decode:
            try:
                data = self._decode(ch, schema, msg)
            except DECODE_ERRORS as exc:
                raise LogError(f"{self.path}: cannot decode the {name or 'schemaless'} message on {ch.topic} at "
                               f"log time {msg.log_time * 1e-9:.6f} s: {exc}") from None
        return LogMessage(topic=ch.topic, schema=name, log_time_ns=msg.log_time, sequence=msg.sequence, data=data)

    def _decode(self, ch, schema, msg: Message):
        name = schema.name if schema else ""
        if ch.message_encoding == "json":
            doc = json.loads(msg.data)
            if name == "rt2.BallObservation":
                return codecs.decode_observation(doc)
            if name == "rt2.Detections":
                return codecs.decode_detections(doc)
            if name == "rt2.GroundTruthBall":
                return codecs.decode_ground_truth(doc)
            if name == "rt2.Figures":
                return doc["figures"]
            return doc
        if ch.message_encoding == "protobuf" and schema is not None:
            pb = self._decoder(ch, schema)(msg.data)
            if name in ("foxglove.CompressedImage", "foxglove.RawImage"):
                return codecs.decode_image(pb)
            if name == "foxglove.FrameTransforms":
                return codecs.decode_transforms(pb)
            if name == "foxglove.JointStates":
                return codecs.decode_joint_states(pb, msg.log_time * 1e-9)
            return pb
        return bytes(msg.data)

    # -- lifetime -------------------------------------------------------------------------------
    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> "SessionLogReader":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
