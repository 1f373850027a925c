"""harness.logs: unfinished, cut and damaged logs; crash loss bounded by the flush period; bounded memory."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
import pytest

from harness.cli import main as rt2_main
from harness.logs import LogWriterOptions, SessionLogReader, SessionLogWriter
from harness.logs._index import build_index, load_chunk
from harness.logs._mcap_writer import LaneSpec, LaneWriter
from harness.logs.synthetic import make_session, write_session

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def finished_log(tmp_path_factory) -> Path:
    """A finished 3 s session, 2 cameras, png images, chunks flushed every 0.5 s of log time."""
    path = tmp_path_factory.mktemp("logs") / "full.mcap"
    s = make_session(3.0, rate_hz=40, n_cameras=2, image_size=(64, 48), n_variants=3, seed=1)
    with SessionLogWriter(path, metadata={"kind": "test"}, image_format="png", flush_period_s=0.5) as w:
        write_session(w, s)
    return path


def _keys(messages):
    return [(m.topic, m.log_time_ns, m.sequence, m.data) for m in messages]


def _chunk_messages(path: Path, chunks):
    """(topic, log time, sequence, bytes) of the messages in ``chunks`` of ``path``, in log-time order."""
    idx = build_index(path)
    out = []
    with open(path, "rb") as f:
        for c in chunks:
            for r in load_chunk(f, c):
                if hasattr(r, "log_time"):
                    out.append((idx.channels[r.channel_id].topic, r.log_time, r.sequence, r.data))
    return sorted(out, key=lambda k: k[1])


# -- truncation --------------------------------------------------------------------------------------
@pytest.mark.parametrize("cut", [20, 0.1, 0.37, 0.5, 0.81, 0.97, -100])
def test_truncated_log_recovers_every_complete_chunk(finished_log, tmp_path, cut):
    data = finished_log.read_bytes()
    n = cut if isinstance(cut, int) and cut > 0 else (len(data) + cut if isinstance(cut, int) else int(len(data) * cut))
    path = tmp_path / "cut.mcap"
    path.write_bytes(data[:n])
    complete = [c for c in build_index(finished_log).chunks if c.offset + c.length <= n]
    with SessionLogReader(path) as r:
        assert not r.finished_cleanly
        rec = r.recovery
        assert rec.recovered_chunks == len(complete)
        got = sorted(_keys(r.messages(decode=False)), key=lambda k: k[1])
        assert got == _chunk_messages(finished_log, complete)
        assert rec.recovered_messages == len(got)
        if cut == -100:  # only the summary was cut: nothing lost
            assert rec.data_complete and "no message lost" in rec.text
        else:
            assert rec.lost_bytes > 0 and f"lost the last {rec.lost_bytes} bytes" in rec.text
        list(r.messages())  # decodes without error
        if n > 20:
            assert r.summary().session["kind"] == "test"


def test_truncated_log_info_reports_losses(finished_log, tmp_path, capsys):
    data = finished_log.read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: len(data) // 2])
    assert rt2_main(["log", "info", str(tmp_path / "cut.mcap")]) == 0
    out = capsys.readouterr().out
    assert "NOT finished cleanly: no footer (the writer was killed or the file was cut)" in out
    assert "recovered" in out and "lost the last" in out
    assert rt2_main(["log", "info", str(tmp_path / "cut.mcap"), "--verify"]) == 1
    assert "the data section is cut off" in capsys.readouterr().out


# -- damage ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("compression", ["zstd", ""])
def test_flipped_byte_in_a_chunk_skips_that_chunk_only(finished_log, tmp_path, capsys, compression):
    chunks = build_index(finished_log).chunks
    victim = [c for c in chunks if c.compression == compression][1]
    data = bytearray(finished_log.read_bytes())
    data[victim.offset + victim.length // 2] ^= 0x40
    path = tmp_path / "bad.mcap"
    path.write_bytes(bytes(data))
    with SessionLogReader(path) as r:
        assert r.finished_cleanly  # the summary is intact; the damage shows when the chunk is read
        with pytest.warns(RuntimeWarning, match=f"damaged chunk at offset {victim.offset} skipped"):
            got = sorted(_keys(r.messages(decode=False)), key=lambda k: k[1])
        assert got == _chunk_messages(finished_log, [c for c in chunks if c is not victim])
        assert any(str(victim.offset) in p for p in r.problems)
        assert any(f"offset {victim.offset}" in p for p in r.verify())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        assert rt2_main(["log", "info", str(path), "--verify"]) == 1
    assert f"damaged chunk at offset {victim.offset} skipped" in capsys.readouterr().out


def test_damage_in_an_unfinished_log_is_skipped_by_the_scan(finished_log, tmp_path):
    chunks = build_index(finished_log).chunks
    victim = chunks[2]
    data = bytearray(finished_log.read_bytes()[: chunks[-1].offset + chunks[-1].length])  # footer and summary gone
    data[victim.offset + victim.length - 20] ^= 0xFF
    (tmp_path / "u.mcap").write_bytes(bytes(data))
    with pytest.warns(RuntimeWarning, match=f"damaged chunk at offset {victim.offset} skipped"):
        r = SessionLogReader(tmp_path / "u.mcap")
    with r:
        assert r.recovery.skipped_chunks[0][0] == victim.offset
        assert sorted(_keys(r.messages(decode=False)), key=lambda k: k[1]) == _chunk_messages(
            finished_log, [c for c in chunks if c is not victim])


def test_unreadable_record_header_is_skipped_to_the_next_intact_chunk(finished_log, tmp_path):
    chunks = build_index(finished_log).chunks
    victim = chunks[3]
    data = bytearray(finished_log.read_bytes()[: chunks[-1].offset + chunks[-1].length])
    data[victim.offset] = 0x7F  # not an MCAP opcode
    (tmp_path / "h.mcap").write_bytes(bytes(data))
    with pytest.warns(RuntimeWarning, match=f"damaged record at offset {victim.offset} skipped \\(opcode 0x7f\\): "
                                            f"\\d+ bytes skipped up to the next intact chunk at offset {chunks[4].offset}"):
        r = SessionLogReader(tmp_path / "h.mcap")
    with r:
        assert r.recovery.recovered_chunks == len(chunks) - 1
        assert len(list(r.messages())) == len(_chunk_messages(finished_log, chunks[:3] + chunks[4:]))


def test_unreadable_record_header_without_an_intact_chunk_after_it_stops_the_scan(finished_log, tmp_path):
    chunks = build_index(finished_log).chunks
    victim = chunks[-1]
    data = bytearray(finished_log.read_bytes()[: victim.offset + victim.length])
    data[victim.offset] = 0x7F
    (tmp_path / "h.mcap").write_bytes(bytes(data))
    with pytest.warns(RuntimeWarning, match=f"unreadable record at offset {victim.offset}"):
        r = SessionLogReader(tmp_path / "h.mcap")
    with r:
        assert r.recovery.recovered_chunks == len(chunks) - 1


# -- crash loss is bounded by the flush period -------------------------------------------------------
def test_killed_writer_loses_at_most_the_flush_period(tmp_path):
    path = tmp_path / "killed.mcap"
    script = textwrap.dedent(f"""
        import os, signal
        from harness.logs import SessionLogWriter
        from harness.logs.synthetic import make_session, write_session
        s = make_session(2.5, rate_hz=100, n_cameras=2, image_size=(32, 24), n_variants=2, seed=0)
        w = SessionLogWriter({str(path)!r}, metadata={{"kind": "crash"}}, image_format="raw", flush_period_s=1.0)
        write_session(w, s)
        os.kill(os.getpid(), signal.SIGKILL)  # no close(): no summary, open chunks never written
    """)
    proc = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, timeout=120)
    assert proc.returncode == -signal.SIGKILL, proc.stderr.decode()
    with SessionLogReader(path) as r:
        assert not r.finished_cleanly
        last_written_s = 2.49
        for topic in ("/tracker/rt2/ball", "/camera/cam1/image"):
            ts = [m.t_s for m in r.messages(topic, decode=False)]
            assert ts and ts == sorted(ts)
            assert last_written_s - ts[-1] <= 1.0 + 1e-6, topic  # at most one flush period lost
            assert len(ts) == round(ts[-1] * 100) + 1  # and nothing before it
        assert r.summary().session["kind"] == "crash"


def test_idle_writer_hands_every_message_older_than_the_flush_period_to_the_os(tmp_path):
    """Messages written, then silence: the timer thread, not a next message, flushes them. The
    child prints the monotonic time at which it handed each message over (the clock is system-wide);
    after a SIGKILL every message handed over more than 1 s before the kill is in the recovered log."""
    path = tmp_path / "idle.mcap"
    script = textwrap.dedent(f"""
        import sys, time
        import numpy as np
        from harness.logs import SessionLogWriter
        w = SessionLogWriter({str(path)!r}, metadata={{"kind": "crash"}}, image_format="png", flush_period_s=1.0)
        img = np.zeros((24, 32, 3), np.uint8)
        for k in range(40):  # 2 s of slow writing; log time advances only 4 ms: only wall time can flush
            w.write_ground_truth(k * 1e-4, [0.0, 0.0, float(k)], None, None, frame_index=k)
            w.write_image(k * 1e-4, "cam0", img, k)
            print(k, time.monotonic(), flush=True)
            time.sleep(0.05)
        print("idle", time.monotonic(), flush=True)
        time.sleep(60)
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    handed = {}
    try:
        for line in proc.stdout:
            word, t = line.split()
            if word == "idle":
                break
            handed[int(word)] = float(t)
        time.sleep(1.6)
        killed_at = time.monotonic()
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait()
    assert len(handed) == 40
    with SessionLogReader(path) as r:
        assert not r.finished_cleanly
        for topic in ("/ground_truth/ball", "/camera/cam0/image"):
            got = {m.sequence for m in r.messages(topic, decode=False)}
            due = {k for k, t in handed.items() if killed_at - t > 1.0}
            assert due == set(range(40)) and due <= got, topic


def test_flush_timer_is_stopped_by_close_and_does_not_keep_a_writer_alive(tmp_path):
    import gc
    import threading
    import weakref

    before = {t for t in threading.enumerate() if t.name == "rt2-log-flush"}
    w = SessionLogWriter(tmp_path / "a.mcap", metadata={"kind": "t"}, flush_period_s=0.05)
    w.write_ground_truth(0.0, [0, 0, 1], None, None)
    (timer,) = {t for t in threading.enumerate() if t.name == "rt2-log-flush"} - before
    t_end = time.monotonic() + 10.0  # the timer's flush, however late a loaded machine runs it (was a 0.2 s sleep)
    while SessionLogReader(tmp_path / "a.mcap").recovery.recovered_messages == 0 and time.monotonic() < t_end:
        time.sleep(0.02)
    assert SessionLogReader(tmp_path / "a.mcap").recovery.recovered_messages == 1  # flushed while idle
    w.close()
    assert not timer.is_alive()
    w2 = SessionLogWriter(tmp_path / "b.mcap", metadata={"kind": "t"}, flush_period_s=0.05)
    ref = weakref.ref(w2._mcap)
    (timer2,) = {t for t in threading.enumerate() if t.name == "rt2-log-flush"} - before
    del w2
    gc.collect()
    assert ref() is None
    timer2.join(1.0)
    assert not timer2.is_alive()


def test_flush_timer_is_thread_safe_with_a_busy_writer(tmp_path):
    """Many small messages while the timer flushes every few ms: the file reads back whole and in order."""
    path = tmp_path / "busy.mcap"
    with SessionLogWriter(path, metadata={"kind": "t"}, flush_period_s=0.004, image_format="png") as w:
        img = np.zeros((8, 8, 3), np.uint8)
        for k in range(3000):
            w.write_ground_truth(k * 1e-6, [0.0, 0.0, float(k)], None, None, frame_index=k)
            if k % 10 == 0:
                w.write_image(k * 1e-6, "cam0", img, k)
    with SessionLogReader(path) as r:
        assert r.finished_cleanly and r.verify() == []
        seqs = [m.sequence for m in r.messages("/ground_truth/ball", decode=False)]
        assert seqs == list(range(3000))
        assert r.summary().n_chunks > 2


def test_wall_clock_flush_hands_old_chunks_to_the_os(tmp_path):
    def messages_on_disk(sleep_s):
        path = tmp_path / f"w{sleep_s}.mcap"
        with open(path, "wb") as f:
            w = LaneWriter(f, {"state": LaneSpec("zstd", 1 << 20)}, flush_period_s=0.2)
            ch = w.register_channel("/x", "json", 0)
            w.add_message("state", ch, 0, b"{}")
            time.sleep(sleep_s)
            w.add_message("state", ch, 1, b"{}")  # same log time window: only wall time can close the chunk
            with SessionLogReader(path) as r:
                return r.recovery.recovered_messages

    assert messages_on_disk(0.0) == 0
    assert messages_on_disk(0.3) == 2


# -- memory ------------------------------------------------------------------------------------------
def test_streaming_read_memory_is_bounded_by_a_chunk_not_the_file(tmp_path):
    path = tmp_path / "big.mcap"
    opts = LogWriterOptions(state_chunk_bytes=64 << 10, image_chunk_bytes=256 << 10)
    s = make_session(4.0, rate_hz=50, n_cameras=2, image_size=(160, 120), n_variants=4, seed=2)
    with SessionLogWriter(path, metadata={"kind": "mem"}, image_format="raw", options=opts) as w:
        write_session(w, s)
    size = path.stat().st_size
    chunk_limit = 256 << 10
    assert size > 40 * chunk_limit
    with SessionLogReader(path) as r:
        tracemalloc.start()
        n = 0
        for m in r.messages():
            n += m.data is not None
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    assert n == r.summary().n_messages
    # at most one image chunk and one state chunk (raw, decompressed and parsed) plus decoder overhead
    assert peak < 6 * chunk_limit + (1 << 20), (peak, size)
    assert peak < size / 5
