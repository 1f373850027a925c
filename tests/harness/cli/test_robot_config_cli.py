"""`rt2 robot check-config` and `--robot NAME|PATH.yaml`: shipped arms pass, a table of hostile robot configs
fails with one line naming the file and the field, exit 2, before anything runs."""

from __future__ import annotations

import re

import pytest

from harness.cli import main
from tests.robot_models.test_arms import _PRISMATIC_URDF, slide_config


def _needs_robot_data():
    pytest.importorskip("example_robot_data", reason="example-robot-data is not installed (pip install 'rt2[robots]')")


# -- smoke -------------------------------------------------------------------------------------------
def test_check_config_of_the_wam(capsys):
    assert main(["robot", "check-config", "wam"]) == 0
    out = capsys.readouterr().out
    assert "45/45 points of the hitting region" in out and "wam_hitting.npz" in out and out.rstrip().endswith("wam: usable")


def test_check_config_shows_the_ik_grid_going(capsys, monkeypatch):
    """A fine --grid takes minutes (~2.5 ms a point): its progress is on stderr (here every update: TQDM_MININTERVAL=0),
    the report on stdout unchanged."""
    monkeypatch.setenv("TQDM_MININTERVAL", "0")
    assert main(["robot", "check-config", "wam", "--grid", "2", "2", "2"]) == 0
    out, err = capsys.readouterr()
    assert "8/8 points of the hitting region" in out and "IK" not in out
    assert "IK: 100%" in err and "8/8" in err


@pytest.mark.parametrize("name", ["panda", "ur10", "xarm7"])
def test_check_config_of_the_shipped_arms(capsys, name):
    _needs_robot_data()
    assert main(["robot", "check-config", name]) == 0
    out = capsys.readouterr().out
    assert "PROBLEM" not in out and out.rstrip().endswith(f"{name}: usable")


def test_sim_reach_takes_a_robot_config(capsys, tmp_path):
    path = slide_config(tmp_path, mount={"xyz_m": [-1.9, 0.0, 0.5]})
    assert main(["sim", "reach", "--robot", str(path), "--grid", "2", "2", "2", "--grow-m", "0", "--json"]) == 0
    assert '"robot": "slide"' in capsys.readouterr().out


# -- bad input: the hostile configs ------------------------------------------------------------------
_FAR = {"xyz_m": [-6.0, 0.0, 0.7]}


@pytest.mark.parametrize("changes, urdf, match", [
    ({"base_link": "plinth"}, None, r"slide\.yaml: .*base_link: link 'plinth' is not in the URDF"),
    ({"flange_link": "wrist"}, None, r"slide\.yaml: .*flange_link: link 'wrist' is not in the URDF"),
    ({}, ('type="revolute"', 'type="continuous"'), r"slide\.yaml: .*joint 'turn' is 'continuous': it has no position limits"),
    ({}, ('<limit lower="-2" upper="2" velocity="2" effort="1"/>', ""), r"slide\.yaml: .*joint 'turn' needs <limit"),
    ({"limits": {"qdot_max_rad_s": [1, 2], "qddot_max_rad_s2": [5, 5], "q_max": [0.6, 2.0]}}, None,
     r"slide\.yaml: limits\.q_max: slide = 0\.6 m is beyond the URDF's range"),
    ({"mount": _FAR}, None, r"slide\.yaml: mount\.xyz_m: the arm cannot reach the hitting region"),
    ({"q_home_rad": None}, None, r"slide\.yaml: q_home_rad must be given for an arm other than the WAM"),
    ({"simulator": {"bandwidth_hz": [6, 6, 6]}}, None, r"slide\.yaml: simulator: SimWamOptions\.bandwidth_hz must be one number or 2"),
])
def test_hostile_config_is_one_line_exit_2(capsys, tmp_path, changes, urdf, match):
    path = slide_config(tmp_path, **changes)
    if urdf is not None:
        (tmp_path / "slide.urdf").write_text(_PRISMATIC_URDF.replace(*urdf))
    assert main(["robot", "check-config", str(path), "--grid", "2", "2", "2"]) == 2
    out = capsys.readouterr().out
    problems = [line for line in out.splitlines() if line.startswith("PROBLEM")]
    assert any(re.search(match, line) for line in problems), problems  # (the slide arm's racket faces the court badly too)
    for argv in (["sim", "reach", "--robot", str(path)], ["accuracy", "--quick", "--robot", str(path), "--out", str(tmp_path / "o")],
                 ["learn", "promp", "--robot", str(path), "--no-save"], ["sim", "wam", "--robot", str(path)]):
        if "simulator" in changes and argv[:2] == ["sim", "reach"]:
            continue  # rt2 sim reach runs no simulator
        if "mount" in changes and argv[:2] == ["sim", "wam"]:
            continue  # rt2 sim wam moves the arm wherever it stands
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "Traceback" not in err and re.search(match, err), (argv, err)


def test_unknown_robot_names_the_shipped_ones(capsys):
    assert main(["sim", "reach", "--robot", "kuka"]) == 2
    assert "unknown robot 'kuka'; shipped: [" in capsys.readouterr().err
    assert main(["robot", "check-config", "kuka"]) == 2
    assert "PROBLEM unknown robot 'kuka'" in capsys.readouterr().out
