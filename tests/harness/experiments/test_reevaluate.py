"""``rt2 reevaluate`` (harness.cli.reevaluate, harness.experiments.accuracy.reevaluate_accuracy): a recorded accuracy session re-run
offline reproduces the live figures exactly, from the images and from the detections; other settings
change them sensibly; a cut log is re-evaluated on what was recovered; bad input is one clear line.
The session is the ``accuracy_session`` fixture of tests/conftest.py."""

from __future__ import annotations

import json
import shutil
import tracemalloc

import numpy as np
import pytest

from harness.experiments.accuracy import AccuracyConfig
from harness.experiments.accuracy.reevaluate_accuracy import reevaluate_accuracy
from harness.cli import main
from harness.logs import SessionLogReader, SessionLogWriter


def _reeval(path, **kw):
    with SessionLogReader(path) as log:
        return reevaluate_accuracy(log, progress=False, **kw)


# -- smoke / exactness ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("source", ["images", "detections"])
def test_same_settings_reproduce_the_live_figures_exactly(accuracy_session, source):
    result, out = accuracy_session
    r = _reeval(out / "session.mcap", source=source)
    assert r.source == source and r.identical
    assert r.rows == result.rows
    assert r.figures["registration"] == result.figures["registration"]
    assert r.figures["faults"] == result.figures["faults"]
    for kind in result.errors:
        np.testing.assert_array_equal(r.errors[kind], result.errors[kind])
    if source == "detections":
        assert "as recorded" in r.how["rtblob"] and "detections" in r.how["rt2"]


def test_detections_carry_blob_areas_and_old_logs_without_them_skip_the_size_test(accuracy_session, monkeypatch):
    import dataclasses

    from harness.logs import codecs

    result, out = accuracy_session
    with SessionLogReader(out / "session.mcap") as log:
        det = next(m.data for m in log.messages(["/camera/cam0/detections"]) if len(m.data.uv_px))
    assert det.areas_px is not None and det.areas_px.shape == (len(det.uv_px),) and (det.areas_px > 0).all()
    assert not any("blob areas" in n for n in _reeval(out / "session.mcap", source="detections", trackers=["rt2"]).notes)
    # a log written before the areas were logged: decoded without them
    decode = codecs.decode_detections
    monkeypatch.setattr(codecs, "decode_detections", lambda doc: dataclasses.replace(decode(doc), areas_px=None))
    r = _reeval(out / "session.mcap", source="detections", trackers=["rt2"])
    assert any("no blob areas" in n and "size test was not re-run" in n for n in r.notes)
    assert r.identical  # nothing was rejected live, so the figures still agree


def test_auto_picks_images_when_every_frame_was_logged(accuracy_session):
    _, out = accuracy_session
    assert _reeval(out / "session.mcap", trackers=["rt2-paper"]).source == "images"


# -- other settings ----------------------------------------------------------------------------------------------
def test_a_tighter_eps_changes_the_figures_sensibly(accuracy_session):
    result, out = accuracy_session
    live = {r["tracker"]: r for r in result.rows}
    tight = _reeval(out / "session.mcap", source="detections", trackers=["rt2", "rt2-paper"], eps_px=1.5)
    assert [r["tracker"] for r in tight.rows] == ["rt2", "rt2-paper"] and not tight.identical
    for row in tight.rows:
        ref = live[row["tracker"]]
        assert row != ref
        # a 1.5 px consistency threshold rejects more: fewer positions, never more
        assert row["frac_missing"] >= ref["frac_missing"]
    # the trackers' rig has the simulated 1.3 px calibration error: below that the cameras never agree,
    # so nothing registers, and the re-evaluation says so in one line
    with pytest.raises(ValueError, match=r"only \d+ of the 24 registration frames have an OK rt2 position"):
        _reeval(out / "session.mcap", source="detections", trackers=["rt2"], eps_px=0.5)
    loose = _reeval(out / "session.mcap", source="detections", trackers=["rt2"], eps_px=6.0)
    assert loose.rows == [live["rt2"]]  # 6 px is the default the live run used


def test_only_the_asked_tracker_is_reported(accuracy_session):
    result, out = accuracy_session
    r = _reeval(out / "session.mcap", source="detections", trackers=["rtblob"])
    assert r.rows == [result.rows[2]] and list(r.errors) == ["rtblob"]


# -- a cut log -----------------------------------------------------------------------------------------------------
def test_truncated_log_is_reevaluated_on_what_was_recovered(accuracy_session, tmp_path):
    _, out = accuracy_session
    cut = tmp_path / "cut.mcap"
    data = (out / "session.mcap").read_bytes()
    cut.write_bytes(data[: int(len(data) * 0.75)])
    r = _reeval(cut, source="detections")
    assert any("not finished cleanly" in n for n in r.notes)
    assert 24 < r.figures["n_present"] < 48
    assert any(f"of 48 frame sets available" in n for n in r.notes)
    assert all(row["frac_missing"] < 1 for row in r.rows)


# -- memory ----------------------------------------------------------------------------------------------------------
def test_reevaluation_streams_the_log(accuracy_session):
    _, out = accuracy_session
    path = out / "session.mcap"
    _reeval(path, source="images", trackers=["rtblob"])  # warm up imports and caches
    tracemalloc.start()
    _reeval(path, source="images", trackers=["rtblob"])
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    size = path.stat().st_size
    assert size > 40e6  # 48 x 4 lossless VGA images
    assert peak < 0.4 * size, f"peak {peak / 1e6:.1f} MB for a {size / 1e6:.1f} MB log"


# -- the command line and bad input -------------------------------------------------------------------------------------
def test_cli_prints_writes_json_and_plot(accuracy_session, tmp_path, capsys):
    result, out = accuracy_session
    js, png = tmp_path / "r.json", tmp_path / "r.png"
    code = main(["reevaluate", str(out / "session.mcap"), "--tracker", "rt2", "--from", "detections", "--no-progress",
                 "--json", str(js), "--plot", str(png)])
    text = capsys.readouterr().out
    assert code == 0 and "reproduced exactly" in text and "from the logged detections" in text
    assert json.loads(js.read_text()) == [result.rows[0]]
    assert png.read_bytes()[:4] == b"\x89PNG"


def _fake_log(path, *, kind="accuracy", config=None, log_images="all"):
    meta = {"kind": kind}
    if config is not None:
        meta["config"] = config.to_dict()
    with SessionLogWriter(path, metadata=meta, log_images=log_images):
        pass
    return path


@pytest.mark.parametrize("make, argv, match", [
    (lambda p: _fake_log(p, kind="tennis"), [], r"cannot re-evaluate a session of kind 'tennis'; known kinds: \['accuracy'"),
    (lambda p: _fake_log(p, config=AccuracyConfig(trackers=("rt2",))), ["--tracker", "rtblob"],
     r"tracker\(s\) \['rtblob'\] were not run in this session; it has \['rt2'\]"),
    (lambda p: _fake_log(p, config=AccuracyConfig(), log_images=5), ["--from", "images"],
     "cannot re-run on images: the log has images of every 5th frame set only"),
    (lambda p: p, [], "no such file"),
    (lambda p: (p.write_bytes(b"not an mcap file at all"), p)[1], [], "not an MCAP file|MCAP"),
])
def test_cli_bad_input_is_one_line(make, argv, match, tmp_path, capsys):
    path = make(tmp_path / "x.mcap")
    code = main(["reevaluate", str(path), "--no-progress", *argv])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    import re

    assert re.search(match, err), err


def test_eps_must_be_positive(accuracy_session, capsys):
    _, out = accuracy_session
    assert main(["reevaluate", str(out / "session.mcap"), "--eps-px", "-2"]) == 2
    assert "--eps-px must be a positive number" in capsys.readouterr().err


def test_copy_of_a_log_reevaluates_the_same(accuracy_session, tmp_path):
    result, out = accuracy_session
    copy = tmp_path / "copy.mcap"
    shutil.copy(out / "session.mcap", copy)
    assert _reeval(copy, source="detections").rows == result.rows
