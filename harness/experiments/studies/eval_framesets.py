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

``rt2-motion`` and ``rt2-motion-gate`` are ``rt2`` with the motion cue of fixed cameras (``TrackerOptions.motion_cue``,
docs/pipeline.md "The motion cue": full frames searched only where the frame moved / searched whole and the candidates
where nothing moved dropped); it needs frames in their time order, so it acts on ``--flight-frames`` sequences, where
each flight is preceded by the session's own frame set before its first (unscored, the trackers with a cue only: the
frames a live camera gave before the ball came).

``rtblob`` is the RTBlob baseline (fixed pairs 0+1, 2+3); ``rt2-trained-sizes`` and ``rtblob-3m`` are ``rt2``
and ``rtblob`` with ``TrackerOptions.size_from_rig=False`` (the model's trained blob areas, RTBlob's template
for a ball 3 m away), to show what the rig's size limits change (docs/pipeline.md, "Size limits from the rig").

Scenes (``--scene``): ``lab`` renders random frame sets of ``--rig`` (above; trackers ``rt2``, ``rt2-no-size``,
``rt2-no-edge``, ``rt2-paper`` by default); ``caliscope`` builds semi-real frame sets on the real 4-camera
caliscope session (:mod:`harness.sim.semireal`: its real frames as backgrounds, its real calibration, one
orange or white ball of known physics flight drawn into every camera with that camera's lens, local light,
sharpness and noise; trackers ``rt2``, ``rt2-paper``, ``rtblob`` by default), and also prints the accuracy
table: percentiles of every position's 3D error, wrong ones included. ``--ball white`` pastes a real white
ball cut from the real rally frames instead (:mod:`harness.sim.real_balls`: at the projection of its 3D
position, its size at that depth, its smear along the projected flight; ``--crop-frames`` chooses the rally
frames, ``--ball-crops`` another COCO set), and its flights run over the session's frames in time order. ``--tracker-rig`` gives the
trackers a second real calibration of the same cameras (``caliscope_4cam_rt2``: ``rt2 calib board`` of the
session's videos, aligned to caliscope's world frame), so the ball drawn with caliscope's calibration is
tracked through a real calibration error.

The frame sets run in chunks of ``CHUNK`` on :mod:`harness.common.executor` (``--workers``, ``--ray``); every
frame set depends only on ``(seed, f)`` and the trackers are reset in between, so the figures do not
depend on the backend or the number of workers. Stopped early (SIGINT, SIGTERM, a lost worker): the
figures of the chunks that finished are printed and written with ``"partial": true``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from harness.common.executor import SweepOptions, add_sweep_arguments, options_from_args, run_sweep
from tracker import MotionOptions, TrackerOptions
from tracker.size_test import EdgeLossFit, SizeTest, fit_edge_loss

__all__ = ["TRACKERS", "FramesetScores", "add_arguments", "evaluate", "format_edge_loss", "format_table", "run", "cameras_with_ball", "score_frameset", "trackable_views"]

#: name -> (Tracker kind, Tracker option overrides)
TRACKERS = {  # rt2 without its ball hypotheses: a frame set alone has no motion to tell the ball in play
    "rt2": ("rt2", {"hypotheses": None}),
    "rt2-no-size": ("rt2", {"max_size_ratio": None, "hypotheses": None}),
    "rt2-no-edge": ("rt2", {"blob_edge_px": 0.0, "max_size_ratio": 1.2, "hypotheses": None}),
    "rt2-paper": ("rt2-paper", {}),
    "rtblob": ("rtblob", {}),
    "rt2-trained-sizes": ("rt2", {"hypotheses": None, "size_from_rig": False}),  # blob areas and window from the model, not the rig
    "rtblob-3m": ("rtblob", {"size_from_rig": False}),  # the template sized for a ball 3 m away, as published
    "rt2-motion": ("rt2", {"hypotheses": None, "motion_cue": MotionOptions()}),  # full frames: searched where something moved
    "rt2-motion-gate": ("rt2", {"hypotheses": None, "motion_cue": MotionOptions(regions=False)}),  # ... whole, then the still candidates dropped
}
#: the scenes (``--scene``): "lab" = rendered random frame sets of ``--rig``; "caliscope" = semi-real frame
#: sets on the real 4-camera caliscope session (:mod:`harness.sim.semireal`)
SCENES = ("lab", "caliscope")
#: trackers scored when ``--trackers`` is not given, per scene
DEFAULT_TRACKERS = {"lab": ("rt2", "rt2-no-size", "rt2-no-edge", "rt2-paper"), "caliscope": ("rt2", "rt2-paper", "rtblob")}
#: error percentiles of the accuracy table (``format_accuracy``)
PERCENTILES = (50, 90, 95, 99)
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
    position_errors_cm: list = None  #: every position's distance to the nearest target ball (inf: none in the frame set)

    def __post_init__(self):
        self.errors_cm = [] if self.errors_cm is None else self.errors_cm
        self.position_errors_cm = [] if self.position_errors_cm is None else self.position_errors_cm
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
        self.position_errors_cm.extend(other.position_errors_cm)

    def error_percentiles_cm(self) -> dict:
        """{"p50": ..., ...} of every position's error (``PERCENTILES``; wrong positions included), cm; None without positions."""
        e = np.asarray(self.position_errors_cm, float)
        return {f"p{q}": (round(float(np.percentile(e, q)), 4) if len(e) else None) for q in PERCENTILES}

    def as_json(self) -> dict:
        out = {k: v for k, v in asdict(self).items() if k not in ("errors_cm", "blob_widths_px", "ball_widths_px", "position_errors_cm")}
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
    scores.position_errors_cm.append(100.0 * float(err.min()) if len(err) else float("inf"))
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


def evaluate(rig, frames: int, seed: int, *, trackers=None, ball_colour: str = "orange", tol_m: float = 0.04,
             model=None, max_size_ratio: float = MAX_SIZE_RATIO, progress=True, sweep: SweepOptions | None = None,
             stopped: list | None = None, scene: str = "lab", semireal=None, session=None, tracker_rig=None,
             flight_frames: int = 1, rate_hz: float = 100.0):  # fmt: skip
    """Render ``frames`` random frame sets of ``rig`` and score each tracker; list of :class:`FramesetScores`.

    trackers : names in ``TRACKERS`` (default: ``DEFAULT_TRACKERS[scene]``)
    scene : one of ``SCENES``; "caliscope" ignores ``rig`` (the session's calibration is the rig) and draws
        the ball into the real frames of ``session`` (a folder, default ``harness.sim.semireal.DEFAULT_SESSION``)
        with :class:`harness.sim.semireal.SemiRealOptions` ``semireal`` (its ``ball_colour`` is ``ball_colour``;
        its ``real_balls`` pastes real white balls, and its flights then need at most the session's frame sets);
        the trackers get the session's calibration, or ``tracker_rig`` (a :class:`tracker.Rig`: another calibration
        of the same cameras, aligned by :func:`harness.sim.semireal.aligned_rig`) for a real calibration error
    flight_frames : (caliscope) 1 = every frame set alone (a new ball, trackers reset, no window search); N > 1 =
        flights of N frame sets at ``rate_hz`` (the trackers run through each flight as they would live: motion
        prediction and window search on, reset between flights; frame set ``f`` is frame ``f % N`` of flight ``f // N``)
    max_size_ratio : the ``rt2`` tracker's 3D size test threshold (``TrackerOptions.max_size_ratio``)
    sweep : where the chunks of frame sets run (default: this process); stopped : if a list is given, a sweep
    stopped early (:class:`harness.common.executor.SweepStopped`) is appended to it and the scores of the chunks
    that finished are returned (else the stop propagates)
    """
    from harness.common.progress import progress_bar

    from tracker.pipeline import load_model

    if scene not in SCENES:
        raise ValueError(f"unknown scene {scene!r}; valid: {list(SCENES)}")
    if isinstance(flight_frames, bool) or not isinstance(flight_frames, (int, np.integer)) or flight_frames < 1:
        raise ValueError(f"flight_frames must be an integer >= 1, got {flight_frames!r}")
    if flight_frames > 1 and scene != "caliscope":
        raise ValueError("flights (flight_frames > 1) are a --scene caliscope mode; --scene lab scores frame sets alone")
    if not (np.isfinite(rate_hz) and 0 < rate_hz <= 10000):
        raise ValueError(f"rate_hz must be a frame rate in (0, 10000] Hz, got {rate_hz!r}")
    trackers = DEFAULT_TRACKERS[scene] if trackers is None else tuple(trackers)
    for name in trackers:
        if name not in TRACKERS:
            raise ValueError(f"unknown tracker {name!r}; valid: {list(TRACKERS)}")
    if ball_colour not in ("orange", "white"):
        raise ValueError(f"ball colour must be 'orange' or 'white', got {ball_colour!r}")
    semi = None
    if scene == "caliscope":
        from dataclasses import replace

        from harness.sim.semireal import DEFAULT_SESSION, SemiRealOptions, aligned_rig, session_rig

        session = DEFAULT_SESSION if session is None else session
        rig = session_rig(session)  # a missing file fails here, not in a worker
        if tracker_rig is not None:
            rig = aligned_rig(tracker_rig, rig)[0]
        semi = (session, replace(SemiRealOptions() if semireal is None else semireal, ball_colour=ball_colour))
        if semi[1].moving and flight_frames > 1:
            from harness.sim.semireal import session_frames

            n = session_frames(session)
            if flight_frames > n:
                raise ValueError(f"--flight-frames {flight_frames}: the flights run over the session's frame sets in time order, "
                                 f"and {session} has {n}")
    if rig.workspace_m is None:
        raise ValueError("the rig has no workspace_m: random frame sets need the box where balls fly")
    model = load_model(model)  # fails here, not in a worker
    setup = (rig, seed, tuple(trackers), ball_colour, tol_m, model, max_size_ratio, semi, (int(flight_frames), float(rate_hz)))
    size = CHUNK if flight_frames == 1 else flight_frames * max(1, CHUNK // flight_frames)  # a flight never straddles two chunks
    chunks = [(a, min(a + size, frames)) for a in range(0, frames, size)]
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


def _init_worker(rig, seed, trackers, ball_colour, tol_m, model, max_size_ratio, semi=None, flights=(1, 100.0)) -> None:
    """Per worker process: the renderer (or the semi-real session, ``semi`` = (folder, options)) and the
    trackers (reset before every frame set)."""
    from harness.sim.render import Renderer
    from harness.sim.render.scene_state import colour_rgb
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
        renderer=None if semi is not None else Renderer(rig, seed=seed),
        flights=flights,
        runs={name: Tracker(rig, TRACKERS[name][0], roi=False if flights[0] == 1 else None, **({} if TRACKERS[name][0] == "rtblob" else {"model": model}), **overrides[name])
              for name in trackers},
    )
    if semi is not None:
        from harness.sim.semireal import SemiRealSession

        _WORKER["session"] = SemiRealSession(semi[0], semi[1], seed=seed)
    _WORKER["widths"] = {name: SizeTest(rig, None, tr.options.ball_radius_m) for name, tr in _WORKER["runs"].items()}


def _score_chunk(chunk: tuple[int, int]) -> dict:
    """Frame sets ``chunk[0] .. chunk[1] - 1`` through every tracker: {tracker: FramesetScores of them}."""
    from harness.sim.render.scenes import random_scene
    from tracker import FrameSet, Status

    w = _WORKER
    rig, seed, tol_m, (lo, hi), runs = w["rig"], w["seed"], w["tol_m"], w["box"], w["runs"]
    scores = {name: FramesetScores(name) for name in runs}
    rejections0 = {name: tr.stats.size_rejections for name, tr in runs.items()}
    n_flight, rate_hz = w["flights"]
    flight = None
    for f in range(*chunk):
        t_s = float(f)
        if w["renderer"] is None and n_flight > 1:  # a frame of a semi-real flight: the trackers keep their motion
            n, j = divmod(f, n_flight)
            if flight is None or j == 0:
                flight = w["session"].flight(n, n_flight, rate_hz)
                for tr in runs.values():
                    tr.reset()
                if flight[0] >= 1 and w["session"].options.moving:  # a fixed camera's stream had frames before the ball came:
                    before = FrameSet(-1.0 / rate_hz, w["session"].background(flight[0] - 1))  # the cue's first background (unscored)
                    for name, tr in runs.items():
                        if tr.options.motion_cue is not None:
                            counted = tr.stats.size_rejections
                            tr.process(before)
                            rejections0[name] += tr.stats.size_rejections - counted  # not scored: not counted
            images, truths, balls_m, _ = w["session"].flight_frameset(n, j, flight)
            ours, t_s = [0], j / rate_hz
        elif w["renderer"] is None:  # semi-real: one ball, the target
            images, truths, balls_m, _ = w["session"].frameset(f)
            ours = [0]
        else:
            scene = random_scene(np.random.default_rng([seed, f]), rig.workspace_m, frame_index=f)
            images, truths = w["renderer"].render_labelled(scene)
            ours = [b for b, ball in enumerate(scene.balls) if np.allclose(ball.colour, w["target"])]
            balls_m = np.array([scene.balls[b].position_m for b in ours]).reshape(-1, 3)
        n_seen = trackable_views(balls_m, [sum(bool(t[b].visible) for t in truths) for b in ours], lo, hi)
        for name, tr in runs.items():
            if n_flight == 1:
                tr.reset()
            obs, info = tr.process_with_info(FrameSet(t_s, images))
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


def format_accuracy(scores) -> str:
    """Accuracy table: percentiles of every position's 3D error (wrong positions included), cm."""
    n = max([12] + [len(s.tracker) for s in scores])
    head = f"{'tracker':<{n}} {'positions':>10} " + " ".join(f"{'p' + str(q) + ' cm':>9}" for q in PERCENTILES)
    lines = [head, "-" * len(head)]
    for s in scores:
        pct = s.error_percentiles_cm()
        lines.append(f"{s.tracker:<{n}} {s.positions:10d} " + " ".join(f"{pct[f'p{q}']:9.2f}" if pct[f"p{q}"] is not None else f"{'-':>9}" for q in PERCENTILES))
    return "\n".join(lines)


def format_table(scores) -> str:
    n = max([12] + [len(s.tracker) for s in scores])  # the tracker column (12 unless a longer name needs more)
    head = f"{'tracker':<{n}} {'recall':>8} {'recall OK':>10} {'wrong':>8} {'wrong OK':>9} {'median cm':>10} {'positions':>10} {'OK':>5} {'trackable':>10} {'size rej.':>10} {'max ratio':>10} {'missed: det.':>13}"
    lines = [head, "-" * len(head)]
    for s in scores:
        missed = f"{s.missed_detector}/{s.trackable - s.found}"
        lines.append(
            f"{s.tracker:<{n}} {100 * s.recall:7.2f}% {100 * s.recall_ok:9.2f}% {100 * s.wrong_rate:7.2f}% {100 * s.wrong_ok_rate:8.2f}% "
            f"{s.median_error_cm:10.3f} {s.positions:10d} {s.ok_positions:5d} {s.trackable:10d} {s.size_rejections:10d} {s.max_right_size_ratio:10.2f} {missed:>13}"
        )
    return "\n".join(lines)


def add_arguments(parser) -> None:
    parser.add_argument("--scene", choices=SCENES, default="lab",
                        help="lab: rendered random frame sets of --rig (default); caliscope: semi-real frame sets, a ball of known flight "
                             "drawn into the real frames of the real 4-camera caliscope session, with its real calibration")
    parser.add_argument("--rig", default=None, help="rig name in data/rigs or a rig YAML path (default lab4_vga_v1, the detector's; --scene lab only)")
    parser.add_argument("--session", default=None, help="--scene caliscope: the session folder (default ../shared/data/real/caliscope_4cam)")
    parser.add_argument("--exposure", default="tracking", help="--scene caliscope: 'tracking' (a 2 ms shutter in every camera, default), "
                        "'recorded' (each webcam's own, 8-31 ms) or a shutter time in seconds")
    parser.add_argument("--sync", choices=("exact", "recorded"), default="exact",
                        help="--scene caliscope: ball drawn at the frame set's time in every camera (exact, default) or at each camera's recorded frame time")
    parser.add_argument("--backgrounds", type=int, default=12, help="--scene caliscope: real frame sets used as backgrounds (default 12 of 48)")
    parser.add_argument("--flight-frames", type=int, default=1,
                        help="--scene caliscope: 1 = every frame set alone (default); N > 1 = flights of N frame sets at --rate-hz, "
                             "the trackers running through each (motion prediction and window search on)")
    parser.add_argument("--rate-hz", type=float, default=100.0, help="--scene caliscope with --flight-frames: frame rate of the flights (default 100)")
    parser.add_argument("--tracker-rig", default=None,
                        help="--scene caliscope: the trackers' calibration (rig name or file, e.g. caliscope_4cam_rt2 = rt2 calib board of the "
                             "session's videos), aligned to the session's world frame; the ball is drawn with caliscope's calibration, so the "
                             "difference is a real calibration error (default: the trackers get caliscope's own)")
    parser.add_argument("--frames", type=int, default=300, help="frame sets to render (default 300)")
    parser.add_argument("--seed", type=int, default=2, help="scene and noise seed (default 2 = the held-out detector set's frames)")
    parser.add_argument("--model", default=None, help="weights file (.npz; default: the shipped model)")
    parser.add_argument("--ball-colour", choices=("orange", "white"), default=None,
                        help="the balls that count as the ball (default orange, the model's; white with --ball white)")
    parser.add_argument("--ball", choices=("orange", "white"), default=None,
                        help="--scene caliscope: orange = the drawn orange ball (the default); white = real white balls cut from the "
                             "real rally frames (--ball-crops) and pasted along the flight; flights then run over the session's "
                             "frames in their time order")
    parser.add_argument("--ball-crops", default=None,
                        help="--ball white: the COCO set whose balls are cut (default ../shared/data/real/phone_rally)")
    parser.add_argument("--crop-frames", default=None,
                        help="--ball white: START:STOP of the crops' time order whose balls are used (e.g. 58: = the rally "
                             "frames a detector trained on 0:58 never saw; default all)")
    parser.add_argument("--tol-m", type=float, default=0.04, help="a position this close to a ball is right, metres (default 0.04 = one ball diameter)")
    parser.add_argument("--max-size-ratio", type=float, default=MAX_SIZE_RATIO,
                        help=f"the rt2 tracker's 3D size test threshold (default {MAX_SIZE_RATIO:g}, TrackerOptions' default)")
    parser.add_argument("--trackers", nargs="+", default=None, choices=list(TRACKERS),
                        help="trackers to score (default: rt2 rt2-no-size rt2-no-edge rt2-paper for --scene lab; rt2 rt2-paper rtblob for caliscope)")
    parser.add_argument("--json", default=None, help="also write the figures as JSON to this path")
    add_sweep_arguments(parser)


def _ball_choice(args) -> tuple[str, dict]:
    """``--ball`` / ``--ball-colour`` / ``--ball-crops`` / ``--crop-frames`` -> (target colour, SemiRealOptions fields)."""
    from harness.sim.semireal import ball_options

    colour = args.ball_colour or ("white" if args.ball == "white" else "orange")
    if args.ball is not None and colour != args.ball:
        raise ValueError(f"--ball {args.ball} and --ball-colour {colour} disagree: the ball pasted is the ball that counts")
    return colour, ball_options(args.ball, args.ball_crops, args.crop_frames)


def _semireal_options(args, ball: dict):
    from harness.sim.semireal import SemiRealOptions

    if args.backgrounds < 1:
        raise ValueError(f"--backgrounds must be >= 1, got {args.backgrounds}")
    if args.flight_frames < 1:
        raise ValueError(f"--flight-frames must be >= 1, got {args.flight_frames}")
    if not (np.isfinite(args.rate_hz) and 0 < args.rate_hz <= 10000):
        raise ValueError(f"--rate-hz must be a frame rate in (0, 10000] Hz, got {args.rate_hz}")
    if args.exposure in ("tracking", "recorded"):
        return SemiRealOptions(exposure=args.exposure, sync=args.sync, backgrounds=args.backgrounds, **ball)
    try:
        t = float(args.exposure)
    except ValueError:
        raise ValueError(f"--exposure must be 'tracking', 'recorded' or a shutter time in seconds, got {args.exposure!r}") from None
    if not (np.isfinite(t) and 0 < t <= 0.1):
        raise ValueError(f"--exposure must be a shutter time in (0, 0.1] s, got {args.exposure!r}")
    return SemiRealOptions(exposure="tracking", tracking_exposure_s=t, sync=args.sync, backgrounds=args.backgrounds, **ball)


def run(args) -> int:
    from harness.common.outputs import atomic_write_json, check_output_file
    from tracker.rig_files import resolve_rig

    check_output_file(args.json, "--json")  # before the frame sets are rendered, not after
    if args.frames < 1:
        raise ValueError(f"--frames must be >= 1, got {args.frames}")
    if not (np.isfinite(args.tol_m) and args.tol_m > 0):
        raise ValueError(f"--tol-m must be a positive number of metres, got {args.tol_m}")
    if not (np.isfinite(args.max_size_ratio) and args.max_size_ratio > 0):
        raise ValueError(f"--max-size-ratio must be a positive number, got {args.max_size_ratio}")
    semireal, rig, tracker_rig = None, None, None
    if args.scene == "caliscope":
        if args.rig is not None:
            raise ValueError("--rig applies to --scene lab; --scene caliscope uses the session's own calibration (--session)")
        args.ball_colour, ball = _ball_choice(args)
        semireal = _semireal_options(args, ball)
        from harness.sim.semireal import DEFAULT_SESSION

        args.rig = f"caliscope_4cam ({args.session or DEFAULT_SESSION})"
        if args.flight_frames > 1:
            args.rig += f"; flights of {args.flight_frames} frame sets at {args.rate_hz:g} Hz (trackers run through each)"
        shutter = "each webcam's own" if semireal.exposure == "recorded" else f"{1e3 * semireal.tracking_exposure_s:g} ms"
        when = "each camera's recorded frame time" if semireal.sync == "recorded" else "one time in all cameras"
        args.rig += f"; shutter {shutter}; ball drawn at {when}"
        if semireal.real_balls is not None:
            args.rig += (f"; real white balls cut from {semireal.real_balls}" + (f" frames {semireal.crop_frames}" if semireal.crop_frames else "")
                         + (", flights over the session's frames in time order" if args.flight_frames > 1 else ""))
        if args.tracker_rig is not None:
            from harness.sim.semireal import aligned_rig, session_rig

            tracker_rig = resolve_rig(args.tracker_rig)
            diff = aligned_rig(tracker_rig, session_rig(args.session or DEFAULT_SESSION))[1]
            args.rig += (f"; trackers' calibration {args.tracker_rig}: rotation {', '.join(f'{v:.2f}' for v in diff['rotation_deg'])} deg, "
                         f"centres {', '.join(f'{v:.0f}' for v in diff['centre_mm'])} mm from caliscope's")
    else:
        for name in ("session", "exposure", "sync", "backgrounds", "tracker_rig", "flight_frames", "rate_hz", "ball", "ball_crops", "crop_frames"):
            if getattr(args, name) != {"exposure": "tracking", "sync": "exact", "backgrounds": 12, "flight_frames": 1, "rate_hz": 100.0}.get(name):
                raise ValueError(f"--{name.replace('_', '-')} applies to --scene caliscope only")
        args.ball_colour = args.ball_colour or "orange"
        args.rig = args.rig or "lab4_vga_v1"
        rig = resolve_rig(args.rig)
    stopped: list = []
    scores = evaluate(rig, args.frames, args.seed, trackers=args.trackers, ball_colour=args.ball_colour, tol_m=args.tol_m, model=args.model,
                      max_size_ratio=args.max_size_ratio, sweep=options_from_args(args), stopped=stopped, scene=args.scene,
                      semireal=semireal, session=args.session, tracker_rig=tracker_rig, flight_frames=args.flight_frames,
                      rate_hz=args.rate_hz)  # fmt: skip
    done = scores[0].framesets if scores else 0
    if stopped:
        print(f"PARTIAL ({stopped[0]}): the figures of the {done} of {args.frames} frame sets that finished")
    recorded = None
    if args.model:  # a learned stage's own record raises the size test's threshold (TrackerOptions.model_size_ratio)
        from tracker import BallDetector, BallSegmentationModel
        from tracker.size_test import size_threshold

        recorded = BallDetector(BallSegmentationModel.load(args.model)).size_ratio
    size = f"rt2's max_size_ratio {args.max_size_ratio:g}" + (
        f" (the model's learned stage records {recorded:g}: the test stops at {size_threshold(args.max_size_ratio, recorded):g})" if recorded else "")
    print(f"rig {args.rig}: {done} random frame sets, seed {args.seed}; {args.ball_colour} balls; right = within {100 * args.tol_m:g} cm; {size}")
    print(format_table(scores))
    if args.scene != "lab":
        print("3D error of every position (wrong ones included):")
        print(format_accuracy(scores))
    edge = format_edge_loss(scores)
    if edge:
        print(edge)
    print(f"goal: wrong OK positions <= {100 * GOALS['wrong_ok_rate']:g} % on every seed (the paper's < 1 % outliers in practice, with margin, where the user reads them)")
    if args.json:
        extra = (lambda s: {"scene": args.scene, "error_percentiles_cm": s.error_percentiles_cm()}) if args.scene != "lab" else (lambda s: {})
        rows = [{**s.as_json(), **extra(s), **({"partial": True} if stopped else {})} for s in scores]
        atomic_write_json(args.json, rows, "--json")
    return stopped[0].exit_code if stopped else 0
