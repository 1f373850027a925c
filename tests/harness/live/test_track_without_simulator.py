"""``rt2 track`` on real cameras (here: image folders through the ``video`` source) never imports the simulator:
the rig is found by ``tracker.rig_files.resolve_rig``, beside the rig, not in ``harness/sim``."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

from tracker.rig_files import resolve_rig

ROOT = Path(__file__).resolve().parents[3]


def test_track_with_a_video_source_imports_no_simulator_module(tmp_path):
    for cam in resolve_rig("lab4_vga").cameras:
        (tmp_path / cam.name).mkdir()
        w, h = cam.image_size
        for k in range(3):
            cv2.imwrite(str(tmp_path / cam.name / f"img{k:03d}.png"), np.full((h, w, 3), 40, np.uint8))
    code = ("import sys\nfrom harness.cli import main\n"
            f"try:\n    rc = main(['track', '--source', 'video', {str(tmp_path)!r}, '--publish', 'none', '--duration', '60'])\n"
            "except SystemExit as exc:\n    rc = exc.code\n"
            "print('RC', rc, sorted(m for m in sys.modules if m.startswith('harness.sim')))\n")
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    last = run.stdout.strip().splitlines()[-1]
    assert last == "RC 0 []", f"rt2 track on image folders: {last}"
