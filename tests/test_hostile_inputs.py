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
from harness.coco import read_coco
from harness.play.profiles import load_profiles
from policies.ball_model import BallParams
from policies.promp import ProMP
from robot_models.config import load_robot_config
from tracker import Rig
from tracker._checks import describe
from tracker.detection.model import BallSegmentationModel
from tracker.files import MAX_CONFIG_BYTES, load_npz_checked, load_yaml_checked, read_bytes_capped
from tests.test_rig import OPENCV_TEMPLATE

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
    assert time.perf_counter() - t0 < 0.1 and len(text) <= 80
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
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
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


def test_yaml_dump_of_our_rig_has_no_aliases(tmp_path):
    """What we write we can read: our writers never emit aliases (safe_dump of fresh lists)."""
    rig = Rig.load(ROOT / "data" / "rigs" / "lab4_vga.yaml")
    rig.save(tmp_path / "r.yaml")
    assert "*" not in (tmp_path / "r.yaml").read_text().replace("# ", "")
    assert Rig.load(tmp_path / "r.yaml").names == rig.names
    assert yaml.safe_load((tmp_path / "r.yaml").read_text())["format"] == "rt2.rig"
