"""The contact sheet of misses and false alarms (harness/experiments/detector/failures.py) that
``rt2 eval detector --figure`` draws: which tiles it finds, and the sheet itself from the command line."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from harness.cli import main
from harness.experiments.detector.coco import LabelledImage
from harness.experiments.detector.failures import contact_sheet, find_failures
from tracker.detection.synthetic import hand_made_model


def _li(boxes, w=128, h=96):
    boxes = np.array(boxes, float).reshape(-1, 4)
    return LabelledImage(Path("x.png"), w, h, boxes, boxes[:, :2] + boxes[:, 2:] / 2 - 0.5)


CASES = [
    # (case, labelled boxes, candidate centres best first, expected [(kind, centre)])
    ("first candidate on the ball", [[10, 10, 8, 8]], [[13.5, 13.5], [60, 60]], []),
    ("ball hit by a later candidate only: no miss, but a false alarm", [[10, 10, 8, 8]], [[60, 60], [14, 14]], [("false alarm", (60, 60))]),
    ("no candidate near the ball: a miss and a false alarm", [[10, 10, 8, 8]], [[60, 60]], [("miss", (13.5, 13.5)), ("false alarm", (60, 60))]),
    ("no candidate at all: a miss", [[10, 10, 8, 8]], np.zeros((0, 2)), [("miss", (13.5, 13.5))]),
    ("image without a ball, a detection: a false alarm", [], [[30, 40]], [("false alarm", (30, 40))]),
    ("image without a ball, nothing found: nothing", [], np.zeros((0, 2)), []),
    ("ball smaller than min_diameter_px missed: not a miss", [[10, 10, 4, 4]], np.zeros((0, 2)), []),
    ("NaN padding is no candidate", [[10, 10, 8, 8]], [[np.nan, np.nan]], [("miss", (13.5, 13.5))]),
    ("just inside one diameter counts as a hit", [[10, 10, 8, 8]], [[13.5 + 7.99, 13.5]], []),
    ("just beyond one diameter does not", [[10, 10, 8, 8]], [[13.5 + 8.01, 13.5]], [("miss", (13.5, 13.5)), ("false alarm", (21.51, 13.5))]),
]


@pytest.mark.parametrize("case,boxes,uv,expected", CASES, ids=[c[0] for c in CASES])
def test_what_counts_as_a_miss_or_a_false_alarm(case, boxes, uv, expected):
    got = find_failures([_li(boxes)], [np.asarray(uv, float)], min_diameter_px=6.0)
    assert [(f.kind, tuple(np.round(f.center_px, 2))) for f in got] == [(k, tuple(np.round(c, 2))) for k, c in expected], case


def test_misses_come_first_in_image_order():
    got = find_failures([_li([[10, 10, 8, 8]]), _li([]), _li([[50, 50, 8, 8]])], [[[90, 90]], [[5, 5]], []])
    assert [(f.kind, f.image) for f in got] == [("miss", 0), ("miss", 2), ("false alarm", 0), ("false alarm", 1)]


def test_sheet_draws_label_and_detection_boxes(tmp_path):
    image = np.full((96, 128, 3), 60, np.uint8)
    path = tmp_path / "img.png"
    cv2.imwrite(str(path), image)
    li = LabelledImage(path, 128, 96, [[40.0, 40.0, 10.0, 10.0]], [[44.5, 44.5]])
    out, n_miss, n_alarm = contact_sheet([li], [np.array([[100.0, 20.0]])], [np.array([[96.0, 16.0, 9.0, 9.0]])],
                                         tmp_path / "sheet.png", tile_px=160)
    assert (n_miss, n_alarm) == (1, 1)
    sheet = cv2.cvtColor(cv2.imread(str(out)), cv2.COLOR_BGR2RGB)
    assert sheet.shape[1] == 760  # header width (two tiles of 160 are narrower)
    tiles = sheet[76 : 76 + 160]
    green = (tiles[..., 1] > 200) & (tiles[..., 0] < 80) & (tiles[..., 2] < 80)
    red = (tiles[..., 0] > 240) & (tiles[..., 1] < 60) & (tiles[..., 2] < 60)
    assert green[:, :160].any() and red[:, 160:320].any()  # the miss shows its label, the false alarm its detection


def test_eval_figure_writes_the_contact_sheet_and_is_deterministic(synthetic_ball_coco, tmp_path, capsys):
    model = hand_made_model().save(tmp_path / "hand.npz")
    data = str(synthetic_ball_coco(30, 1))
    for run in ("a", "b"):
        fig = tmp_path / run / "fig.png"
        fig.parent.mkdir()
        assert main(["eval", "detector", "--data", data, "--model", str(model), "--figure", str(fig), "--t-high", "0.97", "--t-low", "0.5"]) == 0
    out = capsys.readouterr().out
    assert "_failures.png: contact sheet of" in out
    a, b = (tmp_path / r / "fig_failures.png" for r in ("a", "b"))
    assert a.read_bytes() == b.read_bytes()  # same data, same sheet
    n_miss = int(out.split("contact sheet of ")[1].split(" misses")[0])
    assert n_miss > 0 and cv2.imread(str(a)).shape[0] > 76 + 160  # a header and at least one row of tiles


def test_figure_sheet_path_checked_before_the_run(synthetic_ball_coco, tmp_path, capsys):
    model = hand_made_model().save(tmp_path / "hand.npz")
    (tmp_path / "fig_failures.png").mkdir()  # the sheet's path is a folder: refused before evaluating
    rc = main(["eval", "detector", "--data", str(synthetic_ball_coco(30, 1)), "--model", str(model), "--figure", str(tmp_path / "fig.png")])
    assert rc == 2 and "fig_failures.png" in capsys.readouterr().err


def test_the_ball_free_figures_show_what_the_table_scored(tmp_path, capsys):
    """``--ball-free --figure``: the contact sheet is of the painted frames (no ball left to miss; a detection anywhere
    is a false alarm), as the table counts them, not of the frames with their balls."""
    from harness.experiments.detector.coco import write_coco
    from tracker.detection.synthetic import ORANGE_RGB, draw_disk

    labelled = []
    (tmp_path / "set").mkdir()
    for i in range(4):
        image = np.full((96, 128, 3), 90, np.uint8)
        draw_disk(image, (20.0 + i, 20.0), 5.0, ORANGE_RGB)  # the labelled ball, first in row-major order
        draw_disk(image, (90.0, 70.0 - i), 5.0, ORANGE_RGB)  # a ball-coloured thing nobody labelled
        path = tmp_path / "set" / f"f{i:06d}_cam0.png"
        cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
        labelled.append(LabelledImage(path, 128, 96, [[15.5 + i, 15.5, 10.0, 10.0]], [[20.0 + i, 20.0]]))
    write_coco(tmp_path / "set", labelled)
    model = hand_made_model().save(tmp_path / "hand.npz")
    fig = tmp_path / "fig.png"
    assert main(["eval", "detector", "--data", str(tmp_path / "set"), "--model", str(model), "--ball-free", "--figure", str(fig)]) == 0
    out = capsys.readouterr().out
    ours = next(line for line in out.splitlines() if line.startswith("ours"))
    assert ours.split()[-1] == "4/4"  # every painted frame still shows the other thing: four false alarms
    assert "contact sheet of 0 misses and 4 false alarms" in out  # (of the frames with their balls: 0 and 0)
