"""``rt2 sim dataset``: a labelled synthetic ball data set (PNG images + one COCO JSON file).

N random frame sets (:func:`harness.sim.render.scenes.random_scene`) are rendered by every camera of
the rig. Each image ``f{frame:06d}_cam{i}.png`` gets one COCO box per ball whose visibility is at
least 0.5 (category ``ball``), with the exact projected centre (``center_px``), the apparent
diameter and the visibility as extra annotation fields; balls seen less than that are listed in
the image's ``hidden_balls`` field instead (not labels, not lost). ``--ball white|orange`` makes every ball
that colour (the scenes are otherwise the same; by default each ball is white or orange at random). Frame f uses the generator
``default_rng([seed, f])`` and the renderer's noise for (seed, f), so the output is byte-identical
for a seed whatever the number of workers. A signal or a lost worker leaves ``--out`` as it was (the
set is rendered into a staging folder and moved into place only when complete).

``--scene caliscope`` writes semi-real sequences instead (:mod:`harness.sim.semireal`): the real frames and
calibration of the 4-camera caliscope session with one ball of known flight, ``--ball white`` = a real
white ball cut from the real rally frames and pasted (``--crop-frames``: which rally frames' balls),
``--ball orange`` = the drawn orange ball. The frame sets come as flights of ``--flight-frames`` at 100 Hz
(frame set ``f`` = frame ``f % N`` of flight ``f // N``; with the white ball each flight runs over the
session's real frames in their time order), so the file names' order is the time order. Each image entry
carries ``camera`` (the session's camera name: train on some cameras, hold out the others), ``frame``,
``flight``, ``flight_frame``, ``background`` (the session's frame set under it) and ``time_s``; each label
the exact projected centre, the apparent diameter, the visibility, the speed and (white) ``crop``: the rally
frame the ball was cut from.
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

from harness.experiments.detector.coco import ANNOTATIONS_FILE, LABEL_COLOURS, LabelledImage, write_coco
from harness.common.executor import Executor, SweepOptions
from harness.common.outputs import OutputError, check_output_dir

__all__ = ["CALISCOPE_FLIGHT_FRAMES", "add_arguments", "generate", "generate_semireal", "run"]

_CHUNK = 8  #: frame sets per worker task
SEMIREAL_RATE_HZ = 100.0  #: the semi-real sequences' frame rate
CALISCOPE_FLIGHT_FRAMES = 24  #: --scene caliscope: frame sets per flight unless --flight-frames says (half the session's 48)


def add_arguments(parser) -> None:
    parser.add_argument("--scene", choices=("lab", "caliscope"), default="lab",
                        help="lab: rendered frame sets of --rig (default); caliscope: semi-real sequences on the real 4-camera caliscope session")
    parser.add_argument("--ball", choices=("orange", "white"), default=None,
                        help="--scene caliscope: white = real white balls cut from the real rally frames and pasted; orange = the drawn orange ball (default); "
                             "--scene lab: every rendered ball of that colour (default: each white or orange at random)")
    parser.add_argument("--session", default=None, help="--scene caliscope: the session folder (default ../shared/data/real/caliscope_4cam)")
    parser.add_argument("--ball-crops", default=None, help="--ball white: the COCO set whose balls are cut (default ../shared/data/real/phone_rally)")
    parser.add_argument("--crop-frames", default=None, help="--ball white: START:STOP of the crops' time order whose balls are used (default all)")
    parser.add_argument("--flight-frames", type=int, default=None,
                        help=f"--scene caliscope: frame sets per flight (default {CALISCOPE_FLIGHT_FRAMES}; at most the session's 48 with --ball white)")
    parser.add_argument("--rig", default="lab4_vga", help="rig name in data/rigs or a rig file (default: lab4_vga; --scene lab)")
    parser.add_argument("--frames", type=int, required=True, help="number of frame sets (each gives one image per camera)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the scenes and the sensor noise (default 0)")
    parser.add_argument("--out", required=True, help="output folder (created; must not hold an annotations.json yet)")
    parser.add_argument("--workers", type=int, default=1, help="processes rendering in parallel (default 1)")
    parser.add_argument("--overwrite", action="store_true", help="replace the annotations.json in --out (images of the old set that the new one does not rewrite stay)")


def run(args) -> int:
    if args.scene == "caliscope":
        if args.rig != "lab4_vga":
            raise ValueError("--rig applies to --scene lab; --scene caliscope uses the session's own calibration (--session)")
        path = generate_semireal(args.frames, args.seed, args.out, ball=args.ball or "orange", session=args.session,
                                 crops=args.ball_crops, crop_frames=args.crop_frames,
                                 flight_frames=CALISCOPE_FLIGHT_FRAMES if args.flight_frames is None else args.flight_frames,
                                 workers=args.workers, overwrite=args.overwrite)
        print(f"wrote {path}")
        return 0
    for name in ("session", "ball_crops", "crop_frames", "flight_frames"):
        if getattr(args, name) is not None:
            raise ValueError(f"--{name.replace('_', '-')} applies to --scene caliscope only")
    path = generate(args.rig, args.frames, args.seed, args.out, workers=args.workers, overwrite=args.overwrite, ball=args.ball)
    print(f"wrote {path}")
    return 0


def _check(frames, seed, workers):
    for name, v, lo in (("--frames", frames, 1), ("--seed", seed, 0), ("--workers", workers, 1)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
            raise ValueError(f"{name} must be an integer >= {lo}, got {v!r}")


def _staged(out, overwrite: bool, write) -> Path:
    """Run ``write(staging)`` (returns its annotations.json) in a staging folder inside ``out`` and move the set
    into place only when complete: a failure leaves ``out`` as it was."""
    out = Path(out)
    if (out / ANNOTATIONS_FILE).exists() and not overwrite:
        raise ValueError(f"--out {str(out)!r} already holds a data set ({ANNOTATIONS_FILE}); choose another folder or pass --overwrite")
    check_output_dir(out, "--out")  # creatable, writable, not full: before rendering
    staging = Path(tempfile.mkdtemp(prefix=".rt2-dataset-", dir=out))
    try:
        json_path = write(staging)
        names = [p.name for p in staging.iterdir() if p.name != ANNOTATIONS_FILE]
        for name in names:
            os.replace(staging / name, out / name)
        os.replace(json_path, out / ANNOTATIONS_FILE)
    except OSError as exc:
        raise OutputError(f"--out {str(out)!r}: cannot write the data set: {exc.strerror or exc} (nothing written)") from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return out / ANNOTATIONS_FILE


def generate(rig, frames: int, seed: int, out, *, workers: int = 1, overwrite: bool = False, progress: bool = True,
             ball: str | None = None) -> Path:
    """Write the data set and return the path of its ``annotations.json`` (see the module docstring).

    rig : a :class:`tracker.Rig`, a rig name in ``data/rigs`` or a rig file
    ball : None = each ball white or orange at random; "white" / "orange" = every ball that colour
        (:attr:`harness.sim.render.scenes.SceneOptions.ball_colour`: the same scenes otherwise)
    """
    from harness.sim.render.scenes import BALL_COLOURS
    from tracker.rig_files import resolve_rig

    _check(frames, seed, workers)
    if ball is not None and ball not in BALL_COLOURS:
        raise ValueError(f"--ball must be one of {list(BALL_COLOURS)}, got {ball!r}")
    rig_obj = resolve_rig(rig)
    # Rendered into a staging folder inside --out, moved into place only when the whole set is written:
    # a failure (disk full, a worker's error) leaves --out as it was.
    return _staged(out, overwrite, lambda staging: _generate_in(rig, rig_obj, frames, seed, staging, workers, progress, ball))


def generate_semireal(frames: int, seed: int, out, *, ball: str = "white", session=None, crops=None, crop_frames: str | None = None,
                      flight_frames: int = CALISCOPE_FLIGHT_FRAMES, workers: int = 1, overwrite: bool = False,
                      progress: bool = True) -> Path:  # fmt: skip
    """Write semi-real caliscope sequences as a COCO data set (module docstring); the path of its ``annotations.json``.

    ball : "white" (real rally balls pasted) or "orange" (drawn); session : the caliscope folder (default
    ``harness.sim.semireal.DEFAULT_SESSION``); crops, crop_frames : the real balls' COCO set (default
    ``DEFAULT_RALLY``) and its ``START:STOP`` range; flight_frames : frame sets per flight (100 Hz)
    """
    from checks.time_order import parse_range
    from harness.sim.semireal import DEFAULT_RALLY, DEFAULT_SESSION, SemiRealOptions, session_frames, session_rig

    _check(frames, seed, workers)
    if ball not in ("orange", "white"):
        raise ValueError(f"--ball must be 'orange' or 'white', got {ball!r}")
    if isinstance(flight_frames, bool) or not isinstance(flight_frames, (int, np.integer)) or flight_frames < 1:
        raise ValueError(f"--flight-frames must be an integer >= 1, got {flight_frames!r}")
    session = Path(DEFAULT_SESSION if session is None else session)
    rig = session_rig(session)  # a missing session fails here, before anything is written
    if ball == "white":
        crops = Path(DEFAULT_RALLY if crops is None else crops)
        if not (crops.is_file() or (crops / ANNOTATIONS_FILE).is_file()):
            raise FileNotFoundError(f"--ball-crops {str(crops)!r}: no COCO {ANNOTATIONS_FILE} there (the real rally frames are ../shared/data/real/phone_rally)")
        if crop_frames is not None:
            parse_range(crop_frames, "--crop-frames")
        options = SemiRealOptions(ball_colour="white", real_balls=str(crops), crop_frames=crop_frames)
        if flight_frames > session_frames(session):
            raise ValueError(f"--flight-frames {flight_frames}: the flights run over the session's frame sets in time order, "
                             f"and {session} has {session_frames(session)}")
    else:
        if crops is not None or crop_frames is not None:
            raise ValueError("--ball-crops and --crop-frames apply to --ball white only")
        options = SemiRealOptions(ball_colour="orange")
    flights = [list(range(a, min(a + flight_frames, frames))) for a in range(0, frames, flight_frames)]
    tasks = [(str(session), options, seed, flight_frames, c) for c in flights]
    info = {
        "description": f"rt2 semi-real sequences (rt2 sim dataset --scene caliscope --ball {ball})",
        "rig": rig.description, "session": str(session), "ball": ball, "frames": int(frames), "seed": int(seed),
        "flight_frames": int(flight_frames), "rate_hz": SEMIREAL_RATE_HZ, "cameras": rig.names,
        "crops": None if ball != "white" else {"source": str(crops), "frames": crop_frames},
        "moving_backgrounds": options.moving,
        "visible_fraction": _visible_fraction(),
        "center_px_convention": "rt2/OpenCV: pixel (0, 0) is the centre of the top-left pixel; bbox is COCO (image = [0, W] x [0, H])",
    }

    def write(staging: Path) -> Path:
        rows = _run_tasks(_semireal_chunk, [(*t, str(staging)) for t in tasks], frames, workers, progress)
        return write_coco(staging, [r[1] for r in rows], [r[2] for r in rows], image_extra=[r[3] for r in rows], info=info)

    return _staged(out, overwrite, write)


def _run_tasks(fn, tasks, frames: int, workers: int, progress: bool) -> list:
    """``fn`` over ``tasks`` here or in worker processes; their rows sorted by key."""
    results = []
    bar = progress_bar(total=frames, desc="rt2 sim dataset", unit="frame set", file=sys.stderr, disable=not progress)
    try:
        if workers == 1:
            for task in tasks:
                results.append(fn(task))
                bar.update(len(task[-2]))
        else:  # worker processes that die with this one; they write into the local staging folder (no --ray)
            with Executor(SweepOptions(workers=min(workers, len(tasks)))) as ex:
                for i, res in ex.map(fn, tasks):
                    results.append(res)
                    bar.update(len(tasks[i][-2]))
    finally:  # the bar ends its line before any error message
        bar.close()
    return sorted((r for chunk in results for r in chunk), key=lambda r: r[0])


def _semireal_chunk(task):
    """Write the frame sets of one flight; rows (key, LabelledImage, extras, image fields)."""
    from harness.sim.semireal import SemiRealSession

    session, options, seed, flight_frames, frames, out = task
    key = ("semireal", session, repr(options), seed)
    if key not in _WORKER:
        _WORKER.clear()
        _WORKER[key] = SemiRealSession(session, options, seed=seed)
    sess = _WORKER[key]
    rig = sess.rig
    n = frames[0] // flight_frames
    flight = sess.flight(n, flight_frames, SEMIREAL_RATE_HZ)
    rows = []
    for f in frames:
        j = f - n * flight_frames
        images, truths, balls_m, k, source = sess.flight_frameset(n, j, flight, crop=True)
        for i, (img, (t,)) in enumerate(zip(images, truths)):
            name = f"f{f:06d}_cam{i}.png"
            if not cv2.imwrite(str(Path(out) / name), cv2.cvtColor(img, cv2.COLOR_RGB2BGR)):
                raise ValueError(f"could not write image {name!r} of the data set (disk full or a file-size limit?)")
            boxes, centers, extras, hidden = [], [], [], []
            if t.visible and t.box_xywh[2] > 0 and t.box_xywh[3] > 0:
                boxes.append(t.box_xywh)
                centers.append(t.center_px)
                extras.append({"diameter_px": round(t.diameter_px, 4), "visibility": round(t.visibility, 4),
                               "speed_mps": round(float(np.linalg.norm(flight[2][j])), 3), "ball": 0,
                               **({"crop": source} if source is not None else {})})
            elif t.visibility > 0:
                hidden.append({"ball": 0, "center_px": [round(float(c), 4) for c in t.center_px], "visibility": round(t.visibility, 4)})
            w, h = rig[i].image_size
            labelled = LabelledImage(Path(name), w, h, np.array(boxes).reshape(-1, 4), np.array(centers).reshape(-1, 2),
                                     ball_colours=(options.ball_colour,) * len(boxes))  # what the ball is, not what it looks like
            fields = {"camera": rig[i].name, "frame": f, "flight": n, "flight_frame": j, "background": int(k),
                      "time_s": round(j / SEMIREAL_RATE_HZ, 6), "hidden_balls": hidden}
            rows.append(((f, i), labelled, extras, fields))
    return rows


def _generate_in(rig, rig_obj, frames: int, seed: int, out: Path, workers: int, progress: bool, ball: str | None = None) -> Path:
    """Render and label into ``out`` (the staging folder); returns the path of its annotations.json."""
    chunks = [list(range(s, min(s + _CHUNK, frames))) for s in range(0, frames, _CHUNK)]
    tasks = [(rig_obj.to_dict(), seed, ball, c, str(out)) for c in chunks]
    rows = _run_tasks(_render_chunk, tasks, frames, workers, progress)
    images = [im for _, im, _, _ in rows]
    extra = [ex for _, _, ex, _ in rows]
    image_extra = [ie for _, _, _, ie in rows]
    info = {
        "description": "rt2 synthetic ball data set (rt2 sim dataset)",
        "rig": rig_obj.description if hasattr(rig, "cameras") else str(rig),
        "frames": int(frames),
        "seed": int(seed),
        "cameras": rig_obj.names,
        **({} if ball is None else {"ball": ball}),
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


def _colour_name(rgb) -> str | None:
    """The ball colour (of :data:`LABEL_COLOURS`) whose reflectance a rendered ball has, or None (another colour)."""
    from harness.sim.render.scene_state import COLOURS

    return next((c for c in LABEL_COLOURS if np.allclose(rgb, COLOURS[c])), None)


def _render_chunk(task):
    """Render and write the frames of one task; returns rows (key, LabelledImage, extras, image fields)."""
    from harness.sim.render.scenes import SceneOptions, random_scene

    rig_dict, seed, ball, frames, out = task
    renderer = _renderer(rig_dict, seed)
    rig = renderer.rig
    options = SceneOptions(ball_colour=ball)
    rows = []
    for f in frames:
        scene = random_scene(np.random.default_rng([seed, f]), rig.workspace_m, options, frame_index=f)
        images, truths = renderer.render_labelled(scene)
        for i, (img, truth) in enumerate(zip(images, truths)):
            name = f"f{f:06d}_cam{i}.png"
            if not cv2.imwrite(str(Path(out) / name), cv2.cvtColor(img, cv2.COLOR_RGB2BGR)):  # cv2 wants BGR
                raise ValueError(f"could not write image {name!r} of the data set (disk full or a file-size limit?)")
            boxes, centers, extras, hidden, colours = [], [], [], [], []
            for b, (ball, t) in enumerate(zip(scene.balls, truth)):
                if t.visible and t.box_xywh[2] > 0 and t.box_xywh[3] > 0:
                    boxes.append(t.box_xywh)
                    centers.append(t.center_px)
                    colours.append(_colour_name(ball.colour))
                    extras.append({"diameter_px": round(t.diameter_px, 4), "visibility": round(t.visibility, 4), "speed_mps": round(float(np.linalg.norm(ball.velocity_mps)), 3), "ball": b})
                elif t.visibility > 0:
                    hidden.append({"ball": b, "center_px": [round(float(c), 4) for c in t.center_px], "visibility": round(t.visibility, 4)})
            w, h = rig[i].image_size
            labelled = LabelledImage(Path(name), w, h, np.array(boxes).reshape(-1, 4), np.array(centers).reshape(-1, 2),
                                     ball_colours=tuple(colours))
            image_fields = {"camera": rig[i].name, "frame": f, "hidden_balls": hidden}
            rows.append(((f, i), labelled, extras, image_fields))
    return rows
