"""The ``rt2 calib`` commands: intrinsics, wand / ball / board extrinsics, robot registration, rendered checks.

Inputs (board specs, videos, image folders, detection CSVs, session logs) in ``inputs.py``; exports
(OpenCV FileStorage, aniposelib calibration.toml) in ``exports.py``; comparisons with a reference or the
truth in ``compare.py``; rendered board views and the end-to-end check in ``rendered.py`` and
``check.py``. The maths is in ``tracker.calibration``. See docs/calibration.md.
"""
