"""Sources for rt2 label's tests: a folder, a video and a session log of small synthetic ball scenes."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from harness.experiments.detector.coco import read_coco


@pytest.fixture()
def ball_folder(synthetic_ball_coco) -> Path:
    """12 synthetic 96x128 scenes (every 5th without a ball) with their true labels in annotations.json."""
    return synthetic_ball_coco(12, 4)


@pytest.fixture()
def ball_truth(ball_folder) -> dict:
    """file name -> (k, 4) true COCO boxes of ``ball_folder``."""
    return {li.path.name: li.boxes_xywh for li in read_coco(ball_folder)}


@pytest.fixture()
def ball_video(ball_folder, tmp_path) -> Path:
    """The 12 scenes as an MJPG .avi (what a phone or webcam recording becomes through OpenCV)."""
    path = tmp_path / "rally.avi"
    files = sorted(ball_folder.glob("*.png"))
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (128, 96))
    assert writer.isOpened()
    for f in files:
        writer.write(cv2.imread(str(f)))
    writer.release()
    return path


@pytest.fixture()
def ball_log(ball_folder, tmp_path) -> Path:
    """A session log (SessionLogWriter, PNG images) of two cameras, 6 frame sets, the scenes as their images."""
    from harness.logs import SessionLogWriter

    path = tmp_path / "session.mcap"
    files = sorted(ball_folder.glob("*.png"))
    with SessionLogWriter(path, metadata={"kind": "test"}, image_format="png") as w:
        for k in range(6):
            for c in range(2):
                rgb = cv2.cvtColor(cv2.imread(str(files[2 * k + c])), cv2.COLOR_BGR2RGB)
                w.write_image(k / 50.0, f"cam{c}", np.ascontiguousarray(rgb), k)
    return path
