"""A seed below 0 is refused by its option before a command runs (numpy's generators take none: their own error,
"expected non-negative integer", named no option and reached the user of ``rt2 sim reach``, ``rt2 sim wam``
and ``rt2 play``)."""

from __future__ import annotations

import pytest

from harness.cli import COMMANDS, main

ROWS = [
    (["sim", "reach", "--seed", "-1"], "--seed must be >= 0, got -1"),
    (["sim", "wam", "--seed", "-4"], "--seed must be >= 0, got -4"),
    (["play", "--seed", "-1"], "--seed must be >= 0, got -1"),
    (["accuracy", "--seed", "-1"], "--seed must be >= 0, got -1"),
    (["eval", "framesets", "--seed", "-2"], "--seed must be >= 0, got -2"),
    (["train", "--data", "NOWHERE", "--out", "OUT", "--seeds", "0", "-2"], "--seeds must be >= 0, got -2"),
    (["label", "NOWHERE", "--out", "OUT", "--train-seed", "-1"], "--train-seed must be >= 0, got -1"),
]


@pytest.mark.parametrize("argv, message", ROWS, ids=[" ".join(a[:2]) for a, _ in ROWS])
def test_a_negative_seed_is_one_line_before_the_command_runs(tmp_path, capsys, argv, message):
    argv = [str(tmp_path / a.lower()) if a in ("NOWHERE", "OUT") else a for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    command = " ".join(argv[:2]) if tuple(argv[:2]) in COMMANDS else argv[0]
    assert err == [f"rt2 {command}: error: {message}"]
    assert list(tmp_path.iterdir()) == []  # nothing made: not even the outputs' folders
