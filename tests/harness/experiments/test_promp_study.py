"""``rt2 learn promp``: runs end to end, same seed -> same primitive and figures, bad arguments -> exit 2."""

from __future__ import annotations

import json

import numpy as np
import pytest

from harness.cli import main
from policies.promp import ProMP

SMALL = ["--demos", "4", "--held-out", "2", "--few", "2", "--n-basis", "6"]


def _run(capsys, out, seed):
    code = main(["learn", "promp", *SMALL, "--seed", str(seed), "--out", str(out), "--json"])
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    assert result.pop("saved") == str(out)
    return result


def test_same_seed_same_primitive_and_figures(tmp_path, capsys):
    a = _run(capsys, tmp_path / "a.npz", 3)
    b = _run(capsys, tmp_path / "b.npz", 3)
    assert a == b
    pa, pb = ProMP.load(tmp_path / "a.npz", robot_id="wam7"), ProMP.load(tmp_path / "b.npz", robot_id="wam7")
    np.testing.assert_array_equal(pa.mu_w, pb.mu_w)
    np.testing.assert_array_equal(pa.Sigma_w, pb.Sigma_w)
    assert pa.metadata["seed"] == 3 and pa.metadata["n_demos"] == 4
    # the figures are what they claim: MAP and ML rows for both training-set sizes, conditioning reached
    assert {(r["n_train"], r["mode"]) for r in a["fits"]} == {(2, "MAP"), (2, "ML"), (4, "MAP"), (4, "ML")}
    assert a["conditioning"]["position"]["failed"] == 0
    assert a["conditioning"]["position"]["racket_error_mm_max"] < 1.0
    c = _run(capsys, tmp_path / "c.npz", 4)
    assert c["fits"] != a["fits"]


def test_table_output_and_no_save(tmp_path, capsys):
    out = tmp_path / "never.npz"
    assert main(["learn", "promp", *SMALL, "--no-save", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "held-out log-likelihood" in text and "position+normal" in text
    assert not out.exists()


@pytest.mark.parametrize("argv, match", [
    (["--few", "1"], "--few must be in"),
    (["--demos", "1"], "--demos must be >= 2"),
    (["--out", "p.yaml"], "--out must end in .npz"),
    (["--pseudo-demos", "0"], "--pseudo-demos must be > 0"),
    # before the demonstrations are made: 0 was named 'n_basis' after them, 1000 'demos[0] has too few samples'
    (["--n-basis", "0"], "--n-basis must be in [2, 100] RBFs per joint, got 0"),
    (["--n-basis", "1000"], "--n-basis must be in [2, 100] RBFs per joint, got 1000"),
])
def test_bad_arguments_exit_2(capsys, argv, match):
    assert main(["learn", "promp", *argv]) == 2
    assert match in capsys.readouterr().err
