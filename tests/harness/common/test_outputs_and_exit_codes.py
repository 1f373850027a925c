"""Outputs respect the umask; exit codes say bad input (2) or a failure at run time such as a lost robot link (1)
(docs/reliability.md); a bad endpoint names the option the user typed."""

from __future__ import annotations

import os
import stat

import pytest

from harness.cli import main
from harness.common.outputs import atomic_write_text
from harness.link.client import LinkLostError


@pytest.mark.parametrize("mask, mode", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664), (0o000, 0o666)])
def test_atomic_writes_get_the_mode_open_would_give(tmp_path, mask, mode):
    old = os.umask(mask)
    try:
        out = atomic_write_text(tmp_path / "a.json", "{}\n")
        plain = tmp_path / "b.json"
        plain.write_text("{}\n")
    finally:
        os.umask(old)
    assert stat.S_IMODE(out.stat().st_mode) == mode == stat.S_IMODE(plain.stat().st_mode)


def test_a_link_lost_at_run_time_exits_1_and_bad_input_2(monkeypatch, capsys):
    import harness.cli.robot_check as robot_check

    def lost(args):
        raise LinkLostError("no joint state from the robot at tcp://127.0.0.1:1 for 0.300 s (limit 0.25 s)")

    monkeypatch.setattr(robot_check, "run", lost)
    assert main(["robot", "check", "--robot", "tcp://127.0.0.1:1"]) == 1
    err = capsys.readouterr().err.strip()
    assert err == "rt2 robot check: error: no joint state from the robot at tcp://127.0.0.1:1 for 0.300 s (limit 0.25 s)"


def test_accuracy_with_no_robot_there_is_bad_input(tmp_path, capsys):
    code = main(["accuracy", "--robot", "tcp://127.0.0.1:9", "--frames", "20", "--trackers", "rt2",
                 "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and "robot link" in err and "did not answer" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("flag", ["--bind", "--state-bind", "--truth-stream"])
def test_robot_serve_names_the_bad_endpoint_option(flag, capsys):
    assert main(["robot", "serve", "--sim", flag, "garbage"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"rt2 robot serve: error: {flag} must be a ZeroMQ endpoint like tcp://127.0.0.1:7650, got 'garbage'"


@pytest.mark.parametrize("args, message", [
    (["--watchdog", "-1"], "--watchdog must be in [0.01, 10] s, got -1.0"),
    (["--watchdog", "nan"], "--watchdog must be in [0.01, 10] s, got nan"),
    (["--batch", "0"], "--batch must be an integer in [1, 50], got 0"),
    (["--clock-skew-ms", "nan"], "--clock-skew-ms must be a number of milliseconds within +-8.64e+07, got nan"),
    (["--clock-skew-ms=-inf"], "--clock-skew-ms must be a number of milliseconds within +-8.64e+07, got -inf"),
    (["--clock-skew-ms", "1e12"], "--clock-skew-ms must be a number of milliseconds within +-8.64e+07, got 1000000000000.0"),
])
def test_robot_serve_names_the_option_of_a_bad_value(args, message, capsys):
    """Not the bridge's field (BridgeOptions.watchdog_s) nor Python's 'cannot convert float NaN to integer'."""
    assert main(["robot", "serve", "--sim", "--duration", "1", *args]) == 2
    assert capsys.readouterr().err.strip() == f"rt2 robot serve: error: {message}"


@pytest.mark.parametrize("name, ok", [("m.npz", True), ("m.npz.tmp", False), ("m.NPZ", False), ("m", False), ("npz", False)])
def test_an_output_of_the_wrong_kind_is_refused_before_its_folder_is_made(tmp_path, name, ok):
    from harness.common.outputs import OutputError, check_output_file

    path = tmp_path / "new" / name
    if ok:
        assert check_output_file(path, "--out", suffix=".npz") == path and path.parent.is_dir()
        return
    with pytest.raises(OutputError, match=rf"^--out must end in \.npz, got '{path}'$"):
        check_output_file(path, "--out", suffix=".npz")
    assert not path.parent.exists()
