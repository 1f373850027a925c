"""``rt2 sim dataset``: a labelled synthetic ball data set (PNG images + one COCO JSON file).

N random frame sets (:func:`harness.sim.render.scenes.random_scene`) are rendered by every camera of
the rig. Each image ``f{frame:06d}_cam{i}.png`` gets one COCO box per ball whose visibility is at
least 0.5 (category ``ball``), with the exact projected centre (``center_px``), the apparent
diameter and the visibility as extra annotation fields; balls seen less than that are listed in
the image's ``hidden_balls`` field instead (not labels, not lost). Frame f uses the generator
``default_rng([seed, f])`` and the renderer's noise for (seed, f), so the output is byte-identical
for a seed whatever the number of workers. A signal or a lost worker leaves ``--out`` as it was (the
set is rendered into a staging folder and moved into place only when complete).
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
from harness.common.progress import progress_bar

from harness.experiments.detector.coco import ANNOTATIONS_FILE, LabelledImage, write_coco
from harness.common.executor import Executor, SweepOptions
from harness.common.outputs import OutputError, check_output_dir

__all__ = ["add_arguments", "generate", "run"]

_CHUNK = 8  #: frame sets per worker task


def add_arguments(parser) -> None:
    parser.add_argument("--rig", default="lab4_vga", help="rig name in data/rigs or a rig file (default: lab4_vga)")
    parser.add_argument("--frames", type=int, required=True, help="number of frame sets (each gives one image per camera)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the scenes and the sensor noise (default 0)")
    parser.add_argument("--out", required=True, help="output folder (created; must not hold an annotations.json yet)")
    parser.add_argument("--workers", type=int, default=1, help="processes rendering in parallel (default 1)")
    parser.add_argument("--overwrite", action="store_true", help="replace the annotations.json in --out (images of the old set that the new one does not rewrite stay)")


def run(args) -> int:
    path = generate(args.rig, args.frames, args.seed, args.out, workers=args.workers, overwrite=args.overwrite)
    print(f"wrote {path}")
    return 0


def _check(frames, seed, workers):
    for name, v, lo in (("--frames", frames, 1), ("--seed", seed, 0), ("--workers", workers, 1)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
            raise ValueError(f"{name} must be an integer >= {lo}, got {v!r}")


def generate(rig, frames: int, seed: int, out, *, workers: int = 1, overwrite: bool = False, progress: bool = True) -> Path:
    """Write the data set and return the path of its ``annotations.json`` (see the module docstring).

    rig : a :class:`tracker.Rig`, a rig name in ``data/rigs`` or a rig file
    """
    from tracker.rig_files import resolve_rig

    _check(frames, seed, workers)
    rig_obj = resolve_rig(rig)
    out = Path(out)
    if (out / ANNOTATIONS_FILE).exists() and not overwrite:
        raise ValueError(f"--out {str(out)!r} already holds a data set ({ANNOTATIONS_FILE}); choose another folder or pass --overwrite")
    check_output_dir(out, "--out")  # creatable, writable, not full: before rendering
    # Render into a staging folder inside --out, moved into place only when the whole set is written:
    # a failure (disk full, a worker's error) leaves --out as it was.
    staging = Path(tempfile.mkdtemp(prefix=".rt2-dataset-", dir=out))
    try:
        json_path = _generate_in(rig, rig_obj, frames, seed, staging, workers, progress)
        names = [p.name for p in staging.iterdir() if p.name != ANNOTATIONS_FILE]
        for name in names:
            os.replace(staging / name, out / name)
        os.replace(json_path, out / ANNOTATIONS_FILE)
    except OSError as exc:
        raise OutputError(f"--out {str(out)!r}: cannot write the data set: {exc.strerror or exc} (nothing written)") from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return out / ANNOTATIONS_FILE


def _generate_in(rig, rig_obj, frames: int, seed: int, out: Path, workers: int, progress: bool) -> Path:
    """Render and label into ``out`` (the staging folder); returns the path of its annotations.json."""
    chunks = [list(range(s, min(s + _CHUNK, frames))) for s in range(0, frames, _CHUNK)]
    tasks = [(rig_obj.to_dict(), seed, str(out), c) for c in chunks]
    results = []
    bar = progress_bar(total=frames, desc="rt2 sim dataset", unit="frame set", file=sys.stderr, disable=not progress)
    try:
        if workers == 1:
            for task in tasks:
                results.append(_render_chunk(task))
                bar.update(len(task[3]))
        else:  # worker processes that die with this one (harness.common.executor); they write into the local
            # staging folder, so the set is rendered on this machine (no --ray)
            with Executor(SweepOptions(workers=min(workers, len(tasks)))) as ex:
                for i, res in ex.map(_render_chunk, tasks):
                    results.append(res)
                    bar.update(len(tasks[i][3]))
    finally:  # the bar ends its line before any error message
        bar.close()
    rows = sorted((r for chunk in results for r in chunk), key=lambda r: r[0])
    images = [im for _, im, _, _ in rows]
    extra = [ex for _, _, ex, _ in rows]
    image_extra = [ie for _, _, _, ie in rows]
    info = {
        "description": "rt2 synthetic ball data set (rt2 sim dataset)",
        "rig": rig_obj.description if hasattr(rig, "cameras") else str(rig),
        "frames": int(frames),
        "seed": int(seed),
        "cameras": rig_obj.names,
        "visible_fraction": _visible_fraction(),
        "center_px_convention": "rt2/OpenCV: pixel (0, 0) is the centre of the top-left pixel; bbox is COCO (image = [0, W] x [0, H])",
    }
    return write_coco(out, images, extra, image_extra=image_extra, info=info)


def _visible_fraction() -> float:
    from harness.sim.render import VISIBLE_FRACTION

    return VISIBLE_FRACTION


_WORKER: dict = {}


def _renderer(rig_dict: dict, seed: int):
    """One renderer per process and rig (the static backgrounds are built once)."""
    from harness.sim.render import Renderer
    from tracker import Rig

    key = (repr(rig_dict), seed)
    if key not in _WORKER:
        _WORKER.clear()
        _WORKER[key] = Renderer(Rig.from_dict(rig_dict), seed=seed)
    return _WORKER[key]


def _render_chunk(task):
    """Render and write the frames of one task; returns rows (key, LabelledImage, extras, image fields)."""
    from harness.sim.render.scenes import random_scene

    rig_dict, seed, out, frames = task
    renderer = _renderer(rig_dict, seed)
    rig = renderer.rig
    rows = []
    for f in frames:
        scene = random_scene(np.random.default_rng([seed, f]), rig.workspace_m, frame_index=f)
        images, truths = renderer.render_labelled(scene)
        for i, (img, truth) in enumerate(zip(images, truths)):
            name = f"f{f:06d}_cam{i}.png"
            if not cv2.imwrite(str(Path(out) / name), cv2.cvtColor(img, cv2.COLOR_RGB2BGR)):  # cv2 wants BGR
                raise ValueError(f"could not write image {name!r} of the data set (disk full or a file-size limit?)")
            boxes, centers, extras, hidden = [], [], [], []
            for b, (ball, t) in enumerate(zip(scene.balls, truth)):
                if t.visible and t.box_xywh[2] > 0 and t.box_xywh[3] > 0:
                    boxes.append(t.box_xywh)
                    centers.append(t.center_px)
                    extras.append({"diameter_px": round(t.diameter_px, 4), "visibility": round(t.visibility, 4), "speed_mps": round(float(np.linalg.norm(ball.velocity_mps)), 3), "ball": b})
                elif t.visibility > 0:
                    hidden.append({"ball": b, "center_px": [round(float(c), 4) for c in t.center_px], "visibility": round(t.visibility, 4)})
            w, h = rig[i].image_size
            labelled = LabelledImage(Path(name), w, h, np.array(boxes).reshape(-1, 4), np.array(centers).reshape(-1, 2))
            image_fields = {"camera": rig[i].name, "frame": f, "hidden_balls": hidden}
            rows.append(((f, i), labelled, extras, image_fields))
    return rows
