"""``rt2 eval framesets``: what the trackers make of the detector's outliers, one 3D position per frame set.

``rt2 eval detector`` scores each camera alone; the paper's point is that the cameras together
survive what fools any one of them. This study renders the same random frame sets as
``rt2 sim dataset`` (``harness.sim.render.scenes.random_scene`` from ``default_rng([seed, f])``, the
renderer's noise for ``(seed, f)``: ``--seed 2`` gives the frames of the held-out detector set),
runs every tracker on each frame set on its own (no motion prior: ``roi=False``, reset in between)
and scores its 3D answer against the scene.

Truth: the scene's balls of ``--ball-colour`` (the model's target; a detection on the other colour
is a wrong answer). A ball is *seen* by a camera when the renderer labels it there (visibility
>= 0.5, the data set's rule). A ball outside the rig's workspace (grown by the estimator's
``workspace_margin_m``; a second ball lying on the floor or a far table corner) is never trackable
-- the estimator rejects points there by design -- but a position on it is not wrong either.

* ``trackable`` = frame sets whose ball is seen by >= 2 cameras (``trackable_3`` : >= 3, enough for
  ``Status.OK``); ``recall`` = of the trackable ones, those with a position within ``--tol-m`` of the
  ball; ``recall_ok`` = of the ``trackable_3`` ones, those with an ``OK`` position within ``--tol-m``;
* a position farther than ``--tol-m`` from every ball (or any position in a frame set without one)
  is **wrong**; ``wrong_rate`` = wrong / positions; ``wrong_ok_rate`` = wrong ``OK`` positions / ``OK``
  positions (what a user who keeps only ``OK`` gets);
* ``median_error_cm``: over the positions within ``--tol-m``;
* ``max_right_size_ratio``: the largest ``PipelineInfo.size_ratio`` of a position within ``--tol-m``
  (for ``rt2-no-size``: how close true balls come to the 3D size test's ``max_size_ratio``;
  for ``rt2`` it cannot exceed it);
  ``size_rejections``: positions the size test rejected;
* ``missed_detector``: trackable frame sets without a right position where at most one camera had the
  ball among its candidates (within a ball diameter): the detector's miss, not the estimator's;
* ``edge_loss_fit``: the detector's edge loss, measured: over the inlier cameras of the right ``OK``
  positions, the least-squares line blob width (``sqrt(4 area / pi)``) = slope x ball width at that
  depth (``2 r f / z``, :meth:`tracker.size_test.SizeTest.widths_px`) - edge loss
  (:func:`tracker.size_test.fit_edge_loss`; the model's ``edge_loss_px``, docs/pipeline.md step 8),
  one per tracker with blob areas (each over its own right OK positions; the figure is rt2's).

Trackers: ``rt2`` (ours, with the 3D size test at ``--max-size-ratio``), ``rt2-no-size`` (ours without it:
``max_size_ratio=None``), ``rt2-no-edge`` (the size test on raw blob widths, ``blob_edge_px=0``, at its
former threshold 1.2: rt2 before 2026-11-25) and ``rt2-paper`` (Algorithms 1 and 2 as published). The rt2
variants run without the ball hypotheses (``TrackerOptions.hypotheses=None``): they choose among several balls
by their motion over frame sets, and a frame set scored alone has none (with them, a frame set showing two
balls would get no position, as the first 50 ms of a live run do); ``rt2 play --scene second_ball`` measures them.

The frame sets run in chunks of ``CHUNK`` on :mod:`harness.common.executor` (``--workers``, ``--ray``); every
frame set depends only on ``(seed, f)`` and the trackers are reset in between, so the figures do not
depend on the backend or the number of workers. Stopped early (SIGINT, SIGTERM, a lost worker): the
figures of the chunks that finished are printed and written with ``"partial": true``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from harness.common.executor import SweepOptions, add_sweep_arguments, options_from_args, run_sweep
from tracker import TrackerOptions
from tracker.size_test import EdgeLossFit, SizeTest, fit_edge_loss

__all__ = ["TRACKERS", "FramesetScores", "add_arguments", "evaluate", "format_edge_loss", "format_table", "run", "cameras_with_ball", "score_frameset", "trackable_views"]

#: name -> (Tracker kind, Tracker option overrides)
TRACKERS = {  # rt2 without its ball hypotheses: a frame set alone has no motion to tell the ball in play
    "rt2": ("rt2", {"hypotheses": None}),
    "rt2-no-size": ("rt2", {"max_size_ratio": None, "hypotheses": None}),
    "rt2-no-edge": ("rt2", {"blob_edge_px": 0.0, "max_size_ratio": 1.2, "hypotheses": None}),
    "rt2-paper": ("rt2-paper", {}),
}
GOALS = {"wrong_ok_rate": 0.005}
MAX_SIZE_RATIO = TrackerOptions().max_size_ratio  #: rt2's size test threshold unless --max-size-ratio says otherwise
CHUNK = 20  #: frame sets per task


@dataclass
class FramesetScores:
    """3D answers of one tracker over the frame sets (module docstring)."""

    tracker: str
    framesets: int = 0
    trackable: int = 0
    trackable_3: int = 0
    found: int = 0
    found_ok: int = 0
    positions: int = 0
    ok_positions: int = 0
    wrong: int = 0
    wrong_ok: int = 0
    size_rejections: int = 0
    missed_detector: int = 0
    max_right_size_ratio: float = float("nan")
    errors_cm: list = None
    blob_widths_px: list = None  #: raw blob width per inlier camera of the right OK positions (edge_loss_fit)
    ball_widths_px: list = None  #: a ball's width at the same cameras' depths

    def __post_init__(self):
        self.errors_cm = [] if self.errors_cm is None else self.errors_cm
        self.blob_widths_px = [] if self.blob_widths_px is None else self.blob_widths_px
        self.ball_widths_px = [] if self.ball_widths_px is None else self.ball_widths_px

    @property
    def recall(self) -> float:
        return self.found / self.trackable if self.trackable else float("nan")

    @property
    def recall_ok(self) -> float:
        return self.found_ok / self.trackable_3 if self.trackable_3 else float("nan")

    @property
    def wrong_rate(self) -> float:
        return self.wrong / self.positions if self.positions else 0.0

    @property
    def wrong_ok_rate(self) -> float:
        return self.wrong_ok / self.ok_positions if self.ok_positions else 0.0

    @property
    def median_error_cm(self) -> float:
        return float(np.median(self.errors_cm)) if self.errors_cm else float("nan")

    @property
    def edge_loss_fit(self) -> EdgeLossFit | None:
        """The edge loss measured on the right OK positions (module docstring); None with too few cameras."""
        try:
            return fit_edge_loss(self.blob_widths_px, self.ball_widths_px)
        except ValueError:
            return None

    def merge(self, other: "FramesetScores") -> None:
        """Add the scores of later frame sets (``other``, same tracker) to these."""
        for k in ("framesets", "trackable", "trackable_3", "found", "found_ok", "positions", "ok_positions", "wrong",
                  "wrong_ok", "size_rejections", "missed_detector"):
            setattr(self, k, getattr(self, k) + getattr(other, k))
        if np.isfinite(other.max_right_size_ratio) and not other.max_right_size_ratio <= self.max_right_size_ratio:
            self.max_right_size_ratio = other.max_right_size_ratio
        self.errors_cm.extend(other.errors_cm)
        self.blob_widths_px.extend(other.blob_widths_px)
        self.ball_widths_px.extend(other.ball_widths_px)

    def as_json(self) -> dict:
        out = {k: v for k, v in asdict(self).items() if k not in ("errors_cm", "blob_widths_px", "ball_widths_px")}
        fit = self.edge_loss_fit
        out["edge_loss_fit"] = None if fit is None else fit.as_json()
        for k in ("recall", "recall_ok", "wrong_rate", "wrong_ok_rate", "median_error_cm", "max_right_size_ratio"):
            v = getattr(self, k)
            out[k] = None if not np.isfinite(v) else round(v, 6)
        return out


def score_frameset(scores: FramesetScores, balls_m, n_seen, position_m, ok: bool, *, tol_m: float, size_ratio: float = float("nan"),
                   widths_px=None) -> None:  # fmt: skip
    """Add one frame set's answer to ``scores``.

    balls_m : (g, 3) the target balls' centres; n_seen : (g,) cameras that see each;
    position_m : (3,) the tracker's position or None; ok : its status is ``OK``;
    size_ratio : the answer's ``PipelineInfo.size_ratio``; widths_px : ``(blob_px, ball_px)`` of the
    answer's inlier cameras (:meth:`tracker.size_test.SizeTest.widths_px`), kept for the edge loss fit
    when the answer is a right ``OK`` position (None: not known)
    """
    balls_m = np.asarray(balls_m, float).reshape(-1, 3)
    n_seen = np.asarray(n_seen, int).reshape(-1)
    scores.framesets += 1
    trackable = bool((n_seen >= 2).any())
    scores.trackable += trackable
    scores.trackable_3 += bool((n_seen >= 3).any())
    if position_m is None:
        return
    scores.positions += 1
    scores.ok_positions += ok
    err = np.linalg.norm(balls_m - np.asarray(position_m, float), axis=1)
    if len(err) and err.min() <= tol_m:
        scores.errors_cm.append(100.0 * float(err.min()))
        if np.isfinite(size_ratio) and not size_ratio <= scores.max_right_size_ratio:
            scores.max_right_size_ratio = float(size_ratio)
        if trackable:
            scores.found += 1
        if ok and (n_seen >= 3).any():
            scores.found_ok += 1
        if ok and widths_px is not None:
            scores.blob_widths_px.extend(np.asarray(widths_px[0], float).tolist())
            scores.ball_widths_px.extend(np.asarray(widths_px[1], float).tolist())
    else:
        scores.wrong += 1
        scores.wrong_ok += ok


def cameras_with_ball(uv_candidates_px, truths) -> int:
    """Cameras among whose candidates ``(n_cams, k, 2)`` one lies within a ball diameter of the ball's
    centre there (``truths``: that ball's :class:`~harness.sim.render.truth.BallTruth` per camera, visible ones only)."""
    n = 0
    for uv, t in zip(uv_candidates_px, truths):
        if t.visible:
            d = np.linalg.norm(uv - np.asarray(t.center_px), axis=1)
            n += bool(np.nanmin(d, initial=np.inf) <= t.diameter_px)
    return n


def trackable_views(balls_m, n_seen, lo, hi) -> np.ndarray:
    """(g,) cameras that see each ball, 0 for a ball outside the box ``[lo, hi]`` (the grown workspace)."""
    balls_m = np.asarray(balls_m, float).reshape(-1, 3)
    inside = ((balls_m >= lo) & (balls_m <= hi)).all(axis=1)
    return np.asarray(n_seen, int).reshape(-1) * inside


def evaluate(rig, frames: int, seed: int, *, trackers=tuple(TRACKERS), ball_colour: str = "orange", tol_m: float = 0.04,
             model=None, max_size_ratio: float = MAX_SIZE_RATIO, progress=True, sweep: SweepOptions | None = None,
             stopped: list | None = None):  # fmt: skip
    """Render ``frames`` random frame sets of ``rig`` and score each tracker; list of :class:`FramesetScores`.

    max_size_ratio : the ``rt2`` tracker's 3D size test threshold (``TrackerOptions.max_size_ratio``)
    sweep : where the chunks of frame sets run (default: this process); stopped : if a list is given, a sweep
    stopped early (:class:`harness.common.executor.SweepStopped`) is appended to it and the scores of the chunks
    that finished are returned (else the stop propagates)
    """
    from harness.common.progress import progress_bar

    from tracker.pipeline import load_model

    for name in trackers:
        if name not in TRACKERS:
            raise ValueError(f"unknown tracker {name!r}; valid: {list(TRACKERS)}")
    if ball_colour not in ("orange", "white"):
        raise ValueError(f"ball colour must be 'orange' or 'white', got {ball_colour!r}")
    if rig.workspace_m is None:
        raise ValueError("the rig has no workspace_m: random frame sets need the box where balls fly")
    model = load_model(model)  # fails here, not in a worker
    setup = (rig, seed, tuple(trackers), ball_colour, tol_m, model, max_size_ratio)
    chunks = [(a, min(a + CHUNK, frames)) for a in range(0, frames, CHUNK)]
    bar = progress_bar(total=frames, desc="eval framesets", unit="frame set", disable=not progress, leave=False)
    with bar:
        parts = run_sweep(sweep or SweepOptions(), _score_chunk, chunks, stopped=stopped, initializer=_init_worker,
                          initargs=setup, on_result=lambda i: bar.update(chunks[i][1] - chunks[i][0]))
    scores = {name: FramesetScores(name) for name in trackers}
    for i in sorted(parts):  # frame order: the same lists as one pass over the frames
        for name in trackers:
            scores[name].merge(parts[i][name])
    return [scores[name] for name in trackers]


_WORKER: dict = {}


def _init_worker(rig, seed, trackers, ball_colour, tol_m, model, max_size_ratio) -> None:
    """Per worker process: the renderer and the trackers (reset before every frame set)."""
    from harness.sim.render import Renderer
    from harness.sim.render.scene import colour_rgb
    from tracker import RobustOptions
    from tracker.pipeline import Tracker

    for tr in _WORKER.get("runs", {}).values():
        tr.close()
    overrides = {name: dict(kw) for name, (_, kw) in TRACKERS.items()}
    overrides["rt2"]["max_size_ratio"] = max_size_ratio
    _WORKER.clear()
    _WORKER.update(
        rig=rig, seed=seed, tol_m=tol_m, target=colour_rgb(ball_colour, "ball_colour"),
        box=rig.workspace_m + np.array([[-1.0], [1.0]]) * RobustOptions().workspace_margin_m,
        renderer=Renderer(rig, seed=seed),
        runs={name: Tracker(rig, TRACKERS[name][0], roi=False, model=model, **overrides[name]) for name in trackers},
    )
    _WORKER["widths"] = {name: SizeTest(rig, None, tr.options.ball_radius_m) for name, tr in _WORKER["runs"].items()}


def _score_chunk(chunk: tuple[int, int]) -> dict:
    """Frame sets ``chunk[0] .. chunk[1] - 1`` through every tracker: {tracker: FramesetScores of them}."""
    from harness.sim.render.scenes import random_scene
    from tracker import FrameSet, Status

    w = _WORKER
    rig, seed, tol_m, (lo, hi), runs = w["rig"], w["seed"], w["tol_m"], w["box"], w["runs"]
    scores = {name: FramesetScores(name) for name in runs}
    rejections0 = {name: tr.stats.size_rejections for name, tr in runs.items()}
    for f in range(*chunk):
        scene = random_scene(np.random.default_rng([seed, f]), rig.workspace_m, frame_index=f)
        images, truths = w["renderer"].render_labelled(scene)
        ours = [b for b, ball in enumerate(scene.balls) if np.allclose(ball.colour, w["target"])]
        balls_m = np.array([scene.balls[b].position_m for b in ours]).reshape(-1, 3)
        n_seen = trackable_views(balls_m, [sum(bool(t[b].visible) for t in truths) for b in ours], lo, hi)
        for name, tr in runs.items():
            tr.reset()
            obs, info = tr.process_with_info(FrameSet(float(f), images))
            sc = scores[name]
            found = sc.found
            widths = None
            if obs.position_m is not None and info.areas_px is not None:  # rt2 kinds: the blob areas of the inlier candidates
                widths = w["widths"][name].widths_px(obs.position_m, info.estimate.candidate_index, info.areas_px)
            score_frameset(sc, balls_m, n_seen, obs.position_m, obs.status is Status.OK, tol_m=tol_m, size_ratio=info.size_ratio, widths_px=widths)
            if (n_seen >= 2).any() and sc.found == found:  # a trackable frame set missed: did the detector give the ball to >= 2 cameras?
                hits = [cameras_with_ball(info.uv_candidates_px, [t[b] for t in truths]) for b, n in zip(ours, n_seen) if n >= 2]
                sc.missed_detector += max(hits) <= 1
    for name, tr in runs.items():
        scores[name].size_rejections = tr.stats.size_rejections - rejections0[name]
    return scores


def format_edge_loss(scores) -> str:
    """One line per tracker with an edge loss fit: the measured line (module docstring)."""
    lines = []
    for s in scores:
        fit = s.edge_loss_fit
        if fit is not None:
            lines.append(f"edge loss fit ({s.tracker}, right OK positions): {fit}")
    return "\n".join(lines)


def format_table(scores) -> str:
    head = f"{'tracker':<12} {'recall':>8} {'recall OK':>10} {'wrong':>8} {'wrong OK':>9} {'median cm':>10} {'positions':>10} {'OK':>5} {'trackable':>10} {'size rej.':>10} {'max ratio':>10} {'missed: det.':>13}"
    lines = [head, "-" * len(head)]
    for s in scores:
        missed = f"{s.missed_detector}/{s.trackable - s.found}"
        lines.append(
            f"{s.tracker:<12} {100 * s.recall:7.2f}% {100 * s.recall_ok:9.2f}% {100 * s.wrong_rate:7.2f}% {100 * s.wrong_ok_rate:8.2f}% "
            f"{s.median_error_cm:10.3f} {s.positions:10d} {s.ok_positions:5d} {s.trackable:10d} {s.size_rejections:10d} {s.max_right_size_ratio:10.2f} {missed:>13}"
        )
    return "\n".join(lines)


def add_arguments(parser) -> None:
    parser.add_argument("--rig", default="lab4_vga_v1", help="rig name in data/rigs or a rig YAML path (default lab4_vga_v1, the detector's)")
    parser.add_argument("--frames", type=int, default=300, help="frame sets to render (default 300)")
    parser.add_argument("--seed", type=int, default=2, help="scene and noise seed (default 2 = the held-out detector set's frames)")
    parser.add_argument("--model", default=None, help="weights file (.npz; default: the shipped model)")
    parser.add_argument("--ball-colour", choices=("orange", "white"), default="orange", help="the balls that count as the ball (default orange, the model's)")
    parser.add_argument("--tol-m", type=float, default=0.04, help="a position this close to a ball is right, metres (default 0.04 = one ball diameter)")
    parser.add_argument("--max-size-ratio", type=float, default=MAX_SIZE_RATIO,
                        help=f"the rt2 tracker's 3D size test threshold (default {MAX_SIZE_RATIO:g}, TrackerOptions' default)")
    parser.add_argument("--trackers", nargs="+", default=list(TRACKERS), choices=list(TRACKERS), help="trackers to score (default all)")
    parser.add_argument("--json", default=None, help="also write the figures as JSON to this path")
    add_sweep_arguments(parser)


def run(args) -> int:
    from harness.common.outputs import atomic_write_json, check_output_file
    from harness.sim.rigs import resolve_rig

    check_output_file(args.json, "--json")  # before the frame sets are rendered, not after
    if args.frames < 1:
        raise ValueError(f"--frames must be >= 1, got {args.frames}")
    if args.seed < 0:
        raise ValueError(f"--seed must be >= 0, got {args.seed}")
    if not (np.isfinite(args.tol_m) and args.tol_m > 0):
        raise ValueError(f"--tol-m must be a positive number of metres, got {args.tol_m}")
    if not (np.isfinite(args.max_size_ratio) and args.max_size_ratio > 0):
        raise ValueError(f"--max-size-ratio must be a positive number, got {args.max_size_ratio}")
    rig = resolve_rig(args.rig)
    stopped: list = []
    scores = evaluate(rig, args.frames, args.seed, trackers=args.trackers, ball_colour=args.ball_colour, tol_m=args.tol_m, model=args.model,
                      max_size_ratio=args.max_size_ratio, sweep=options_from_args(args), stopped=stopped)  # fmt: skip
    done = scores[0].framesets if scores else 0
    if stopped:
        print(f"PARTIAL ({stopped[0]}): the figures of the {done} of {args.frames} frame sets that finished")
    print(
        f"rig {args.rig}: {done} random frame sets, seed {args.seed}; {args.ball_colour} balls; right = within {100 * args.tol_m:g} cm; "
        f"rt2's max_size_ratio {args.max_size_ratio:g}"
    )
    print(format_table(scores))
    edge = format_edge_loss(scores)
    if edge:
        print(edge)
    print(f"goal: wrong OK positions <= {100 * GOALS['wrong_ok_rate']:g} % on every seed (the paper's < 1 % outliers in practice, with margin, where the user reads them)")
    if args.json:
        rows = [{**s.as_json(), **({"partial": True} if stopped else {})} for s in scores]
        atomic_write_json(args.json, rows, "--json")
    return stopped[0].exit_code if stopped else 0
