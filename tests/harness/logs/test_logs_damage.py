"""harness.logs: damaged headers are bounded and skipped, `--verify` fails on them, and a log that lost
only its summary is re-evaluated whole (docs/reliability.md, docs/logging.md "Recovery")."""

from __future__ import annotations

import struct
import tracemalloc
import warnings
import zlib
from pathlib import Path

import numpy as np
import pytest

from harness.cli import main as rt2_main
from harness.logs import SessionLogReader, SessionLogWriter
from harness.logs._index import MAX_CHUNK_BYTES, build_index, load_chunk
from tests.harness.logs.test_logs_recovery import finished_log  # noqa: F401 (the fixture: a finished 3 s png session)


def _keys(messages):
    return sorted(((m.topic, m.log_time_ns, m.sequence, bytes(m.data)) for m in messages), key=lambda k: (k[1], k[0]))


def _expected(path: Path, chunks) -> list:
    idx = build_index(path)
    out = []
    with open(path, "rb") as f:
        for c in chunks:
            out += [(idx.channels[r.channel_id].topic, r.log_time, r.sequence, bytes(r.data))
                    for r in load_chunk(f, c) if hasattr(r, "log_time")]
    return sorted(out, key=lambda k: (k[1], k[0]))


def _damage(src: Path, dst: Path, offset: int, junk: bytes, keep: int | None = None) -> Path:
    data = bytearray(src.read_bytes()[:keep])
    data[offset:offset + len(junk)] = junk
    dst.write_bytes(bytes(data))
    return dst


# -- random bytes over a chunk's header ------------------------------------------------------------------------
@pytest.mark.parametrize("seed", range(6))
def test_random_bytes_over_an_image_chunk_header_skip_that_chunk(finished_log, tmp_path, capsys, seed):
    chunks = build_index(finished_log).chunks
    victim = [c for c in chunks if c.compression == ""][1]
    path = _damage(finished_log, tmp_path / "bad.mcap", victim.offset, np.random.default_rng(seed).bytes(1000))
    tracemalloc.start()
    with SessionLogReader(path) as r:
        with pytest.warns(RuntimeWarning, match=f"damaged chunk at offset {victim.offset} skipped"):
            got = _keys(r.messages(decode=False))
        assert got == _expected(finished_log, [c for c in chunks if c is not victim])
        problems = r.verify()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 64e6  # no allocation driven by a length read from the damaged header
    assert problems[0].startswith(f"damaged chunk at offset {victim.offset} skipped")
    assert len([p for p in problems if p.startswith("damaged chunk")]) == 1  # the other chunks are fine
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        assert rt2_main(["log", "info", str(path), "--verify"]) == 1
    out = capsys.readouterr().out
    assert f"damaged chunk at offset {victim.offset} skipped" in out and "every chunk read back" not in out


@pytest.mark.parametrize("seed", range(3))
def test_unfinished_log_resumes_after_a_damaged_header(finished_log, tmp_path, seed):
    """Without a summary the scan cannot use an index: it finds the next intact chunk (header and CRC)."""
    chunks = build_index(finished_log).chunks
    victim = [c for c in chunks if c.compression == "zstd"][2]
    last = chunks[-1]
    path = _damage(finished_log, tmp_path / "u.mcap", victim.offset, np.random.default_rng(seed).bytes(40),
                   keep=last.offset + last.length)
    with pytest.warns(RuntimeWarning, match=f"damaged record at offset {victim.offset} skipped"):
        r = SessionLogReader(path)
    with r:
        assert not r.finished_cleanly and r.recovery.skipped_chunks[0][0] == victim.offset
        assert f"skipped 1 damaged chunks at offsets {victim.offset}" in r.recovery.text
        assert _keys(r.messages(decode=False)) == _expected(finished_log, [c for c in chunks if c is not victim])


def test_huge_declared_uncompressed_size_is_refused_not_allocated(finished_log, tmp_path):
    chunks = build_index(finished_log).chunks
    victim = [c for c in chunks if c.compression == "zstd"][1]
    # Chunk record: opcode, length, start, end, uncompressed_size (offset 25), ...
    path = _damage(finished_log, tmp_path / "big.mcap", victim.offset + 25, struct.pack("<Q", 1 << 62))
    tracemalloc.start()
    with SessionLogReader(path) as r:
        with pytest.warns(RuntimeWarning, match=rf"damaged chunk at offset {victim.offset} skipped \(McapError: the chunk "
                                                 rf"declares {1 << 62} uncompressed bytes, more than the {MAX_CHUNK_BYTES}"):
            list(r.messages(decode=False))
    assert tracemalloc.get_traced_memory()[1] < 64e6
    tracemalloc.stop()


def test_declared_size_smaller_than_the_data_is_damage(finished_log, tmp_path):
    chunks = build_index(finished_log).chunks
    victim = [c for c in chunks if c.compression == "zstd"][1]
    with open(finished_log, "rb") as f:
        f.seek(victim.offset + 25)
        size = struct.unpack("<Q", f.read(8))[0]
    path = _damage(finished_log, tmp_path / "small.mcap", victim.offset + 25, struct.pack("<Q", size - 100))
    with SessionLogReader(path) as r:
        assert any(p.startswith(f"damaged chunk at offset {victim.offset} skipped (McapError: the chunk holds more "
                                f"than {size - 100} uncompressed bytes") for p in r.verify())


def test_attachment_with_a_damaged_index_length_is_a_clear_error(finished_log, tmp_path):
    with SessionLogWriter(tmp_path / "a.mcap", metadata={"kind": "test"}) as w:
        w.attach("model.npz", b"x" * 100)
    with SessionLogReader(tmp_path / "a.mcap") as r:
        offset, length, media, size = r._index.attachments["model.npz"]
        r._index.attachments["model.npz"] = (offset, 1 << 62, media, size)  # what a damaged index would say
        with pytest.raises(ValueError, match=r"attachment 'model.npz' at offset \d+ is damaged \(its length"):
            r.attachment("model.npz")


# -- only the summary cut --------------------------------------------------------------------------------------
def test_log_without_only_its_summary_is_data_complete(finished_log, tmp_path):
    data = finished_log.read_bytes()
    (tmp_path / "s.mcap").write_bytes(data[:-100])
    with SessionLogReader(tmp_path / "s.mcap") as r:
        assert not r.finished_cleanly and r.data_complete
        assert "no message lost" in r.recovery.text
        with SessionLogReader(finished_log) as full:
            assert _keys(r.messages(decode=False)) == _keys(full.messages(decode=False))
        assert r.verify() == []


def test_reevaluating_a_log_without_only_its_summary_keeps_every_frame_set(accuracy_session, tmp_path):
    from harness.experiments.accuracy.reevaluate_accuracy import reevaluate_accuracy

    result, out = accuracy_session
    data = (out / "session.mcap").read_bytes()
    summary_start = struct.unpack("<Q", data[-8 - 29 + 9: -8 - 29 + 17])[0]
    (tmp_path / "s.mcap").write_bytes(data[:summary_start + 10])
    with SessionLogReader(tmp_path / "s.mcap") as log:
        assert not log.finished_cleanly and log.data_complete
        r = reevaluate_accuracy(log, progress=False, source="detections")
    assert any("every frame set is in it" in n for n in r.notes)
    assert r.figures["n_present"] == result.figures["n_present"]
    assert r.rows == result.rows


def test_crc_of_a_chunk_is_still_checked(finished_log, tmp_path):
    """The bounded decompression keeps the CRC check: one flipped byte in a zstd chunk's data."""
    chunks = build_index(finished_log).chunks
    victim = [c for c in chunks if c.compression == "zstd"][0]
    data = bytearray(finished_log.read_bytes())
    data[victim.offset + victim.length - 3] ^= 0x01
    (tmp_path / "f.mcap").write_bytes(bytes(data))
    with SessionLogReader(tmp_path / "f.mcap") as r:
        problems = r.verify()
    assert any(p.startswith(f"damaged chunk at offset {victim.offset} skipped") for p in problems)
    assert zlib.crc32(b"") == 0


# -- hostile content ------------------------------------------------------------------------------------
def test_a_rig_attachment_with_yaml_aliases_is_refused(tmp_path):
    from tests.test_hostile_inputs import ALIAS_BOMB

    with SessionLogWriter(tmp_path / "h.mcap", metadata={"kind": "test"}) as w:
        w.attach("rig.yaml", ALIAS_BOMB.encode())
    with SessionLogReader(tmp_path / "h.mcap") as r:
        with pytest.raises(ValueError, match=r"h\.mcap: attachment rig\.yaml: not valid YAML: YAML aliases \(\*a\) are not allowed"):
            r.rig()


def test_deeply_nested_json_metadata_is_kept_as_text(tmp_path):
    from harness.logs._mcap_writer import LaneSpec, LaneWriter

    deep = "[" * 100_000 + "]" * 100_000
    with open(tmp_path / "d.mcap", "wb") as f:
        w = LaneWriter(f, {"state": LaneSpec()})
        w.add_metadata("session", {"kind": '"test"', "config": deep})
        w.finish()
    with SessionLogReader(tmp_path / "d.mcap") as r:
        assert r.metadata("session") == {"kind": "test", "config": deep}
