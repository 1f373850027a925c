"""Hostile and malformed input files, and outputs that cannot be written (docs/reliability.md).

Each case is what a user or a damaged disk can hand us; each asserts the one-line message (the file
and field named) and, for commands, exit code 2 and that nothing was written.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import time
import tracemalloc
import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml

from harness.cli import main as rt2_main
from harness.experiments.detector.coco import read_coco
from harness.experiments.play.profiles import load_profiles
from policies.ball_model import BallParams
from policies.promp import ProMP
from robot_models.config import load_robot_config
from tracker import Rig
from checks.arrays import describe
from tracker.detection.model import BallSegmentationModel
from checks.files import MAX_CONFIG_BYTES, load_npz_checked, load_yaml_checked, read_bytes_capped
from tests.tracker.test_rig import OPENCV_TEMPLATE

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_MODEL = ROOT / "data" / "models" / "ball_seg_default.npz"

#: under 400 bytes that expand to 9**10 (3.5e9) strings: the "billion laughs" of YAML
ALIAS_BOMB = "\n".join(
    ['a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    + [f"{c}: &{c} [" + ",".join([f"*{p}"] * 9) + "]" for p, c in zip("abcdefghi", "bcdefghij")]
) + "\n"


# -- YAML alias bombs, huge files, devices ----------------------------------------------------------
def test_the_alias_bomb_is_small():
    assert len(ALIAS_BOMB) < 500


@pytest.mark.parametrize("loader", ["rig", "opencv", "robot", "ball_params"])
def test_alias_bomb_is_refused_quickly_in_every_yaml_loader(tmp_path, loader):
    path = tmp_path / "bomb.yaml"
    path.write_text(ALIAS_BOMB)
    load = {"rig": Rig.load, "opencv": lambda p: Rig.from_opencv_files([p]), "robot": load_robot_config,
            "ball_params": BallParams.load}[loader]
    tracemalloc.start()
    t0 = time.perf_counter()
    try:
        with pytest.raises(ValueError, match=r"bomb\.yaml.*YAML aliases .* are not allowed .*line 2, column"):
            load(path)
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    assert time.perf_counter() - t0 < 2.0 and peak < 20e6


def test_aliases_are_refused_even_when_small(tmp_path):
    path = tmp_path / "cfg.yaml"
    path.write_text("a: &x 1\nb: *x\n")
    with pytest.raises(ValueError, match=r"YAML aliases \(\*x\)"):
        load_yaml_checked(path)
    path.write_text("a: &x 1\nb: 2\n")  # an anchor alone is harmless
    assert load_yaml_checked(path) == {"a": 1, "b": 2}


def test_error_messages_never_expand_a_huge_value():
    """The error helper once built the whole repr of the value it quoted (a bomb's never finishes)."""
    inner = ["lol"] * 9
    for _ in range(9):  # 9**10 strings by reference, as an alias bomb parses
        inner = [inner] * 9
    t0 = time.perf_counter()
    text = describe(inner)
    assert time.perf_counter() - t0 < 2.0 and len(text) <= 80
    assert text.startswith("[[[")


def test_huge_rig_file_is_refused_without_reading_it(tmp_path):
    path = tmp_path / "big.yaml"
    with open(path, "wb") as f:
        f.truncate(200 << 20)  # 200 MB, sparse: costs no disk
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=r"rig file '.*big\.yaml' is 200 MiB, more than the 4 MiB a rig file may have"):
        Rig.load(path)
    assert time.perf_counter() - t0 < 1.0


def test_link_to_dev_zero_is_read_only_up_to_the_cap(tmp_path):
    path = tmp_path / "zero.yaml"
    path.symlink_to("/dev/zero")
    with pytest.raises(ValueError, match=r"rig file '.*zero\.yaml' is longer than the 4 MiB .*not a regular file"):
        Rig.load(path)
    with pytest.raises(ValueError, match=r"calibration file '.*zero\.yaml' is longer than"):
        Rig.from_opencv_files([path])
    with pytest.raises(ValueError, match=r"COCO file '.*zero\.yaml' is longer than"):
        read_coco(path)
    with pytest.raises(ValueError, match="longer than"):
        read_bytes_capped(path, 1000, "file")


def test_a_pipe_as_a_rig_is_refused_without_waiting(tmp_path):
    path = tmp_path / "fifo.yaml"
    os.mkfifo(path)
    with pytest.raises(ValueError, match=r"rig file '.*fifo\.yaml' is a pipe or socket, not a file"):
        Rig.load(path)


def test_deeply_nested_yaml_is_refused(tmp_path):
    path = tmp_path / "deep.yaml"
    path.write_text("a: " + "[" * 10_000 + "]" * 10_000 + "\n")
    with pytest.raises(ValueError, match=r"deep\.yaml: (YAML nested too deeply|not valid YAML)"):
        Rig.load(path)


def test_huge_profiles_and_coco_files_are_refused(tmp_path):
    path = tmp_path / "profiles.json"
    with open(path, "wb") as f:
        f.truncate(MAX_CONFIG_BYTES + 1)
    with pytest.raises(ValueError, match=r"profiles file '.*profiles\.json' is 4 MiB, more than the 4 MiB"):
        load_profiles(path)
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(ValueError, match=r"deep\.json: JSON nested too deeply"):
        load_profiles(deep)


# -- OpenCV calibration import -----------------------------------------------------------------------
@pytest.mark.parametrize("rows", ['"3"', "3.0", "~", "-3", "0", "true"])
def test_opencv_rows_must_be_a_positive_int_named_with_file_and_field(tmp_path, rows):
    p = tmp_path / "cam.yaml"
    p.write_text(OPENCV_TEMPLATE.replace("extrinsics:\n  rows: 3", f"extrinsics:\n  rows: {rows}"))
    assert f"rows: {rows}" in p.read_text()
    with pytest.raises(ValueError, match=r"cam\.yaml: field 'extrinsics': rows must be a positive integer, got"):
        Rig.from_opencv_files([p])


def test_opencv_negative_cols_names_file_and_field(tmp_path):
    p = tmp_path / "cam.yaml"
    p.write_text(OPENCV_TEMPLATE.replace("rows: 1\n  cols: 5", "rows: -1\n  cols: -5"))
    with pytest.raises(ValueError, match=r"cam\.yaml: field 'distortion_coefficients': rows must be a positive integer, got -1"):
        Rig.from_opencv_files([p])


@pytest.mark.parametrize("how", ["opencv", "rig", "cli"])
def test_binary_file_as_a_rig_names_the_file(tmp_path, how, capsys):
    p = tmp_path / "photo.yaml"
    p.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4)
    match = r"file '.*photo\.yaml' is not a UTF-8 text file \(byte 0 is b'\\x89'\)"
    if how == "opencv":
        with pytest.raises(ValueError, match="calibration " + match):
            Rig.from_opencv_files([p])
    elif how == "rig":
        with pytest.raises(ValueError, match="rig " + match):
            Rig.load(p)
    else:
        assert rt2_main(["sim", "dataset", "--rig", str(p), "--frames", "1", "--out", str(tmp_path / "ds")]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and "photo.yaml" in err and "utf-8' codec" not in err
        assert not (tmp_path / "ds").exists()


# -- model files -------------------------------------------------------------------------------------
def _model_fields(**changes):
    with np.load(DEFAULT_MODEL) as npz:
        data = {k: npz[k] for k in npz.files}
    data.update(changes)
    return data


def test_complex_kernel_is_refused(tmp_path):
    data = _model_fields()
    data["kernel"] = data["kernel"].astype(np.complex128) + 1j
    np.savez(tmp_path / "m.npz", **data)
    with pytest.raises(ValueError, match=r"m\.npz: field 'kernel' has unsupported dtype complex128 \(real numbers"):
        BallSegmentationModel.load(tmp_path / "m.npz")
    with pytest.raises(ValueError, match="kernel must be real numbers, got dtype complex128"):
        BallSegmentationModel(kernel=data["kernel"], bias=0.0)


def test_zero_input_scale_is_refused(tmp_path):
    np.savez(tmp_path / "m.npz", **_model_fields(input_scale=np.array([1 / 255, 0.0, 1 / 255])))
    with pytest.raises(ValueError, match=r"m\.npz: .*input_scale must be non-zero for every channel"):
        BallSegmentationModel.load(tmp_path / "m.npz")


def test_random_bytes_model_never_advises_allow_pickle(tmp_path):
    path = tmp_path / "m.npz"
    path.write_bytes(np.random.default_rng(0).bytes(4096))
    with pytest.raises(ValueError, match=r"model file '.*m\.npz' is not a readable \.npz archive \(not a zip file") as err:
        BallSegmentationModel.load(path)
    assert "pickle" not in str(err.value)


def test_pickled_member_is_refused_without_advice_to_unpickle(tmp_path):
    path = tmp_path / "m.npz"
    np.savez(path, **_model_fields(description=np.array([{"evil": 1}], dtype=object)))
    with pytest.raises(ValueError, match=r"field 'description' holds pickled Python objects, which rt2 never loads") as err:
        BallSegmentationModel.load(path)
    assert "allow_pickle" not in str(err.value)


def test_zip_bomb_model_is_refused_before_decompressing(tmp_path):
    path = tmp_path / "bomb.npz"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
        with zf.open("kernel.npy", "w", force_zip64=True) as f:
            chunk = bytes(1 << 20)
            for _ in range(300):  # 300 MiB of zeros, ~0.3 MB compressed
                f.write(chunk)
    assert path.stat().st_size < 2 << 20
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=r"bomb\.npz' would decompress to 300 MiB, more than the 256 MiB allowed"):
        load_npz_checked(path)
    with pytest.raises(ValueError, match=r"ProMP file '.*bomb\.npz' would decompress"):
        ProMP.load(path)
    assert time.perf_counter() - t0 < 1.0


# -- COCO annotations --------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["/etc/passwd", "../outside.png", "sub/../../outside.png"])
def test_coco_file_name_may_not_leave_the_data_folder(tmp_path, name):
    data = tmp_path / "data"
    data.mkdir()
    (tmp_path / "outside.png").write_bytes(b"x")
    doc = {"images": [{"id": 1, "file_name": name, "width": 10, "height": 10}], "annotations": [],
           "categories": [{"id": 1, "name": "ball"}]}
    (data / "annotations.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=r"annotations\.json: image id 1: field 'file_name' .* must be a path inside "
                                         r"the data folder .*\(relative, without '\.\.'\)"):
        read_coco(data)


@pytest.mark.parametrize("field, value", [("width", "x" * 1_000_000), ("bbox", list(range(1_000_000)))])
def test_coco_errors_quote_huge_values_shortened(tmp_path, field, value):
    (tmp_path / "a.png").write_bytes(b"x")
    doc = {"images": [{"id": 1, "file_name": "a.png", "width": 10, "height": 10}],
           "annotations": [{"id": 1, "image_id": 1, "category_id": 1, "bbox": [1, 1, 2, 2]}],
           "categories": [{"id": 1, "name": "ball"}]}
    (doc["images"][0] if field == "width" else doc["annotations"][0])[field] = value
    (tmp_path / "annotations.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=f"field '{field}'") as err:
        read_coco(tmp_path)
    assert len(str(err.value)) < 400


def test_rig_errors_quote_huge_values_shortened(tmp_path):
    path = tmp_path / "r.yaml"
    path.write_text(yaml.safe_dump({"format": "y" * 1_000_000, "version": 1, "cameras": []}))
    with pytest.raises(ValueError, match="field 'format' must be 'rt2.rig', got 'yyy") as err:
        Rig.load(path)
    assert len(str(err.value)) < 400


def test_yaml_dump_of_our_rig_has_no_aliases(tmp_path):
    """What we write we can read: our writers never emit aliases (safe_dump of fresh lists)."""
    rig = Rig.load(ROOT / "data" / "rigs" / "lab4_vga.yaml")
    rig.save(tmp_path / "r.yaml")
    assert "*" not in (tmp_path / "r.yaml").read_text().replace("# ", "")
    assert Rig.load(tmp_path / "r.yaml").names == rig.names
    assert yaml.safe_load((tmp_path / "r.yaml").read_text())["format"] == "rt2.rig"


# -- training data -----------------------------------------------------------------------------------
def test_validation_split_without_balls_is_refused_before_training(tmp_path):
    import cv2

    from harness.experiments.detector.coco import LabelledImage
    from harness.experiments.detector.train import TrainOptions, split_groups, train

    labelled = []
    for i, has_ball in enumerate([True, True, False]):
        path = tmp_path / f"f{i:06d}_cam0.png"
        cv2.imwrite(str(path), np.zeros((48, 64, 3), np.uint8))
        boxes = [[20.0, 20.0, 8.0, 8.0]] if has_ball else np.zeros((0, 4))
        centers = [[23.5, 23.5]] if has_ball else np.zeros((0, 2))
        labelled.append(LabelledImage(path, 64, 48, boxes, centers))
    seed = next(s for s in range(50)
                if not any(li.n_balls for li in split_groups(labelled, 0.3, np.random.default_rng(s))[1]))
    with pytest.raises(ValueError, match=rf"no ball boxes among the 1 validation images \(val_fraction 0.3, seed {seed}\): "
                                         "the thresholds and the recall cannot be measured"):
        train(labelled, TrainOptions(epochs=1, seed=seed, val_fraction=0.3, threshold_choice="split"), progress=False)


# -- output paths ------------------------------------------------------------------------------------
def _no_work(monkeypatch):
    """Make every command's real work fail loudly: an output error must come before it."""
    import harness.experiments.accuracy.experiment as acc
    import harness.cli.reevaluate as ree
    import harness.experiments.studies.bench_estimator as bes
    import harness.experiments.play.bench as bpol
    import harness.experiments.studies.eval_filters as evf
    import harness.experiments.studies.fit_flight as ff
    import harness.cli.play as playexp
    import harness.experiments.studies.eval_framesets as evfs
    import policies.promp_demos as demos
    import harness.experiments.studies.eval_detector as evd
    import harness.experiments.studies.sim_dataset as sds
    import harness.experiments.studies.table1 as t1
    import harness.experiments.detector.train as trd

    def boom(*a, **k):
        raise AssertionError("the work started before the outputs were checked")

    monkeypatch.setattr(acc, "simulate_motion", boom)
    monkeypatch.setattr(sds, "_generate_in", boom)
    monkeypatch.setattr(t1, "run_table1", boom)
    monkeypatch.setattr(trd, "train", boom)
    monkeypatch.setattr(evd, "evaluate", boom)
    monkeypatch.setitem(ree.REEVALUATORS, "accuracy", boom)
    monkeypatch.setattr(evf, "run_study", boom)
    monkeypatch.setattr(ff, "run_study", boom)
    monkeypatch.setattr(demos, "collect_demonstrations", boom)
    monkeypatch.setattr(bes, "bench", boom)
    monkeypatch.setattr(bpol, "bench_policy", boom)
    monkeypatch.setattr(evfs, "evaluate", boom)
    monkeypatch.setattr(playexp, "run_configuration", boom)


def _commands(tmp_path, synthetic_ball_coco):
    """Each command with an output, as a function of that output's path."""
    from harness.logs import SessionLogWriter

    log = tmp_path / "run.mcap"
    if not log.exists():
        with SessionLogWriter(log, metadata={"kind": "accuracy"}):
            pass
    data = str(synthetic_ball_coco(10, 0))
    return {
        "accuracy --out": lambda p: ["accuracy", "--frames", "20", "--no-log", "--out", p],
        "accuracy --json": lambda p: ["accuracy", "--frames", "20", "--no-log", "--out", str(tmp_path / "acc"), "--json", p],
        "sim dataset --out": lambda p: ["sim", "dataset", "--frames", "1", "--out", p],
        "sim table1 --json": lambda p: ["sim", "table1", "--trials", "10", "--json", p],
        "train --out": lambda p: ["train", "--data", data, "--epochs", "1", "--learned", "off", "--out", p + ".npz"],
        "reevaluate --json": lambda p: ["reevaluate", str(log), "--json", p],
        "reevaluate --plot": lambda p: ["reevaluate", str(log), "--plot", p + ".png"],
        "eval detector --json": lambda p: ["eval", "detector", "--data", data, "--json", p],
        "eval filters --json": lambda p: ["eval", "filters", "--no-real", "--sim", "2", "--json", p],
        "sim fit-flight --json": lambda p: ["sim", "fit-flight", "--json", p],
        "learn promp --out": lambda p: ["learn", "promp", "--out", p + ".npz"],
        "bench estimator --json": lambda p: ["bench", "estimator", "--json", p],
        "eval framesets --json": lambda p: ["eval", "framesets", "--frames", "2", "--json", p],
        "play --json": lambda p: ["play", "--balls", "1", "--no-log", "--no-figure", "--json", p],
        "play --out": lambda p: ["play", "--balls", "1", "--out", p],
        "bench policy --json": lambda p: ["bench", "policy", "--balls", "2", "--json", p],
    }


COMMANDS_WITH_OUTPUTS = ["accuracy --out", "accuracy --json", "sim dataset --out", "sim table1 --json", "train --out",
                         "reevaluate --json", "reevaluate --plot", "eval detector --json", "eval filters --json",
                         "sim fit-flight --json", "learn promp --out", "bench estimator --json",
                         "eval framesets --json", "play --json", "play --out", "bench policy --json"]


def _one_line_exit_2(argv, capsys, *patterns):
    """Exit 2 and one line on stderr besides progress bars (tqdm lines hold '%|')."""
    assert rt2_main(argv) == 2
    lines = [ln for ln in capsys.readouterr().err.replace("\r", "\n").splitlines() if ln.strip() and "%|" not in ln]
    assert len(lines) == 1, lines
    err = lines[0]
    for p in patterns:
        assert p in err, err
    return err


@pytest.mark.parametrize("command", COMMANDS_WITH_OUTPUTS)
def test_output_under_an_existing_file_fails_before_the_work(command, tmp_path, capsys, monkeypatch, synthetic_ball_coco):
    argv = _commands(tmp_path, synthetic_ball_coco)[command]
    blocker = tmp_path / "a_file"
    blocker.write_text("keep me")
    _no_work(monkeypatch)
    target = str(blocker) if command in ("accuracy --out", "sim dataset --out", "play --out") else str(blocker / "x")
    _one_line_exit_2(argv(target), capsys, "a_file", "exists and is a")
    assert blocker.read_text() == "keep me"


@pytest.mark.parametrize("command", COMMANDS_WITH_OUTPUTS)
def test_output_in_a_place_nobody_may_write_fails_before_the_work(command, tmp_path, capsys, monkeypatch, synthetic_ball_coco):
    """/sys refuses new files even to root (a folder's mode bits do not stop root; see docs/reliability.md)."""
    if os.access("/sys", os.W_OK) and Path("/sys/rt2-probe").exists():
        pytest.skip("/sys is writable here")
    argv = _commands(tmp_path, synthetic_ball_coco)[command]
    _no_work(monkeypatch)
    _one_line_exit_2(argv("/sys/rt2-nowhere/out"), capsys, "cannot create folder '/sys/rt2-nowhere")


@pytest.mark.parametrize("command", ["accuracy --out", "sim table1 --json", "train --out", "eval detector --json"])
def test_full_disk_is_refused_before_the_work(command, tmp_path, capsys, monkeypatch, synthetic_ball_coco):
    import harness.common.outputs as outputs

    argv = _commands(tmp_path, synthetic_ball_coco)[command]
    _no_work(monkeypatch)
    real = os.statvfs

    def full(path):
        st = real(path)
        return os.statvfs_result((st.f_bsize, st.f_frsize, st.f_blocks, 0, 0, st.f_files, st.f_ffree, st.f_favail,
                                  st.f_flag, st.f_namemax))

    monkeypatch.setattr(outputs.os, "statvfs", full)
    _one_line_exit_2(argv(str(tmp_path / "o" / "out")), capsys, "no space left on the device holding")


def _limited(argv, limit_bytes: int, cwd=ROOT):
    """Run ``rt2 argv`` in a child whose files may not grow beyond ``limit_bytes`` (RLIMIT_FSIZE, SIGXFSZ
    ignored: a write past it fails with EFBIG, as on a full disk)."""
    import signal

    def limit():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))

    return subprocess.run([sys.executable, "-m", "harness.cli", *argv], cwd=cwd, preexec_fn=limit,
                          capture_output=True, text=True, timeout=300)


def test_disk_full_while_writing_the_json_is_one_line_and_leaves_nothing(tmp_path):
    out = tmp_path / "t.json"
    out_old = tmp_path / "old.json"
    out_old.write_text("[]\n")
    argv = ["sim", "table1", "--trials", "10", "--cameras", "4", "--outlier-rates", "5", "--no-progress"]
    # numba writes its disk cache on a kernel's first compile: under a 400-byte limit that write fails first
    # (EFBIG inside numba, no file name), so whether the JSON's error is reached depended on the cache being
    # warm. Warm it the way a user's earlier run would, without the limit.
    warm = subprocess.run([sys.executable, "-m", "harness.cli", *argv], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert warm.returncode == 0, warm.stderr
    proc = _limited([*argv, "--json", str(out)], 400)
    assert proc.returncode == 2, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last == (f"rt2 sim table1: error: --json {str(out)!r}: cannot write: file too large (a file-size limit "
                    "of this process or the file system) (nothing written)")
    assert "Traceback" not in proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.json"]  # no out, no temporary file


def test_atomic_write_keeps_the_old_file_when_the_new_one_cannot_be_written(tmp_path):
    path = tmp_path / "rows.json"
    path.write_text('["old"]\n')
    script = ("import sys; from harness.common.outputs import atomic_write_json\n"
              f"atomic_write_json({str(path)!r}, ['x' * 5000])\n")
    import signal

    def limit():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (1000, 1000))

    proc = subprocess.run([sys.executable, "-c", script], cwd=ROOT, preexec_fn=limit, capture_output=True, text=True)
    assert proc.returncode == 1 and "OutputError" in proc.stderr and "file too large" in proc.stderr
    assert path.read_text() == '["old"]\n' and [p.name for p in tmp_path.iterdir()] == ["rows.json"]


def test_disk_full_while_rendering_a_data_set_leaves_the_folder_as_it_was(tmp_path, capsys, monkeypatch):
    """The data set is rendered into a staging folder; an image that cannot be written (here the
    third) removes it, and --out keeps only what it held before."""
    import cv2

    import harness.experiments.studies.sim_dataset as sds

    d = Rig.load(ROOT / "data" / "rigs" / "lab4_vga.yaml").to_dict()
    for cam in d["cameras"]:  # the lab rig at 160x120: quick to render
        cam["image_size"] = [160, 120]
        cam["K"] = (np.array(cam["K"]) * [[0.25], [0.25], [1.0]]).tolist()
    Rig.from_dict(d).save(tmp_path / "tiny.yaml")
    out = tmp_path / "ds"
    out.mkdir()
    (out / "mine.txt").write_text("keep")
    calls = []
    real = cv2.imwrite

    def imwrite(path, img):
        calls.append(path)
        if len(calls) == 3:
            Path(path).write_bytes(b"\x89PNG half")  # what a full disk leaves behind
            return False
        return real(path, img)

    monkeypatch.setattr(sds.cv2, "imwrite", imwrite)
    _one_line_exit_2(["sim", "dataset", "--rig", str(tmp_path / "tiny.yaml"), "--frames", "1", "--out", str(out)], capsys,
                     "could not write image 'f000000_cam2.png' of the data set (disk full or a file-size limit?)")
    assert sorted(p.name for p in out.iterdir()) == ["mine.txt"]


def test_an_output_that_is_a_folder_is_refused(tmp_path, capsys, monkeypatch, synthetic_ball_coco):
    _no_work(monkeypatch)
    argv = _commands(tmp_path, synthetic_ball_coco)["sim table1 --json"]
    (tmp_path / "d").mkdir()
    _one_line_exit_2(argv(str(tmp_path / "d")), capsys, f"--json {str(tmp_path / 'd')!r} is a folder; give a file name")
