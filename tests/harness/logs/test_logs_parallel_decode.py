"""Images decoded ahead by threads (``SessionLogReader.messages(workers=)``): the same messages in the same
order as decoding in the caller's thread, whatever the worker count; early stops and bad values."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from harness.logs import LogError, SessionLogReader, SessionLogWriter
from harness.logs.reader import MAX_DECODE_WORKERS
from harness.logs.synthetic import make_session, write_session


@pytest.fixture(scope="module")
def jpeg_log(tmp_path_factory):
    path = tmp_path_factory.mktemp("decode") / "s.mcap"
    s = make_session(0.5, rate_hz=60.0, n_cameras=3, image_size=(96, 72), n_variants=4, seed=0)
    with SessionLogWriter(path, metadata={"kind": "test", "seed": 0}, image_format="jpeg") as w:
        write_session(w, s)
    return path


def _same(a, b) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b)
    return repr(a) == repr(b)


@pytest.mark.parametrize("workers", [1, 2, 5])
def test_decoding_ahead_gives_the_same_messages_in_the_same_order(jpeg_log, workers):
    with SessionLogReader(jpeg_log) as r:
        ref = list(r.messages())
        got = list(r.messages(workers=workers))
    assert sum(m.topic.endswith("/image") for m in ref) == 3 * 30  # every image of every camera is there
    assert [(m.topic, m.sequence, m.log_time_ns, m.schema) for m in got] == \
        [(m.topic, m.sequence, m.log_time_ns, m.schema) for m in ref]
    assert all(_same(a.data, b.data) for a, b in zip(got, ref))


def test_an_early_stop_leaves_no_decoding_thread_behind(jpeg_log):
    with SessionLogReader(jpeg_log) as r:
        it = r.messages(["/camera/*/image"], workers=3)
        first = [next(it) for _ in range(5)]
        it.close()
        ref = list(r.messages(["/camera/*/image"]))[:5]
    assert all(_same(a.data, b.data) for a, b in zip(first, ref))
    assert not [t for t in threading.enumerate() if t.name.startswith("log decode")]


def test_an_image_that_fails_to_decode_is_the_same_error_at_the_same_place_with_workers(jpeg_log, monkeypatch):
    from harness.logs import codecs

    decode = codecs.decode_image
    with SessionLogReader(jpeg_log) as r:
        target = [m for m in r.messages(["/camera/cam1/image"], decode=False)][7].log_time_ns

    def failing(pb):  # one image of the log is not a valid JPEG (as cv2.imdecode would say)
        if pb.frame_id == "cam1" and pb.timestamp.ToNanoseconds() == target:
            raise LogError("image data is not a valid jpeg image")
        return decode(pb)

    monkeypatch.setattr(codecs, "decode_image", failing)
    seen = {}
    with SessionLogReader(jpeg_log) as r:
        for workers in (0, 3):
            n = 0
            with pytest.raises(LogError, match=r"cannot decode the foxglove.CompressedImage message on /camera/cam1/image "
                                               r"at log time .*: image data is not a valid jpeg"):
                for _ in r.messages(workers=workers):
                    n += 1
            seen[workers] = n
    assert seen[0] == seen[3] > 0  # every message before the bad one, and none after


@pytest.mark.parametrize("bad", [-1, MAX_DECODE_WORKERS + 1, 1.5, "2", True, None])
def test_bad_worker_counts_are_refused_before_reading(jpeg_log, bad):
    with SessionLogReader(jpeg_log) as r:
        with pytest.raises(LogError, match=r"workers must be a whole number in \[0, 64\]"):
            r.messages(workers=bad)
