"""The motion cue of a fixed camera: which parts of its frame moved, cheaply, at reduced resolution.

In a lab the cameras do not move and the frames of each come in their time order, so what moved since the
last frames is known for little: the ball in flight moves, the lamps, shelves, white walls and sneakers a
detector mistakes for a ball mostly do not. :class:`MotionCue` keeps one camera's background and tells, for
a new frame, which cells of it differ from that background:

1. the frame is looked at in cells of about ``cell_px`` pixels a side, each by the pixel at its centre (a VGA frame:
   160 x 120 cells; a ball at least ``cell_px`` wide always covers one; no averaging: at 12 grey levels the
   threshold is several times a camera's noise);
2. a cell *moved* when one of its channels differs from the background's by more than
   ``threshold + relative x`` the background's brightest channel there (the relative part lets a lamp
   flicker with the mains without moving);
3. when more than ``max_share`` of the cells moved, the scene changed as a whole (the light went on, the
   camera was bumped, another recording begins): the frame gives no cue and becomes the background;
   likewise the first frame, the first after a gap of more than ``max_gap_s`` between frames, and one stamped
   earlier than the frame before it (the clock went back: another recording, a replay started again);
4. the background follows the frames it is computed for: ``bg += alpha (frame - bg)`` per cell (a ball
   passing through a cell leaves a trace of ``alpha`` of its contrast, under the threshold). It is computed
   for every ``learn_every``-th frame, and for every frame whose cue is asked for (a full-frame search); the
   moving cells are those of the frame against the background of the frames before it.

:meth:`MotionCue.moved` tells which candidates lie on moving cells (within their radius plus ``margin_cells``);
where there is no cue every candidate passes. The tracker uses it on full-frame searches only
(``TrackerOptions.motion_cue``): a new ball is one that moves; a ball already followed in windows is kept
when it stops (a ball held still on the robot's end effector, a ball lying on the table); and every
``still_search_s`` (0.5 s) a camera's full-frame search ignores the cue (:meth:`MotionCue.whole_frame_due`), so a ball
lying still that was never followed is found too.

:func:`observe_reference` is the plain numpy version of the per-frame kernel (steps 1, 2 and 4 in one pass over the
cells), :func:`observe_cells` the compiled one (a test checks they agree).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numba
import numpy as np

from checks.numba_cache import key_cache_on_callees

__all__ = ["CameraCues", "MotionCue", "MotionOptions", "observe_cells", "observe_reference", "reduced_size", "sample_points"]


@dataclass(frozen=True)
class MotionOptions:
    """Options of :class:`MotionCue` (module docstring).

    cell_px : a cell of the reduced frame is this many of the camera's pixels a side (VGA: 4 -> 160 x 120 cells)
    alpha : the background's rate of following the frames it is computed for
    learn_every : the background is computed for every this-many-th frame at least (1 = every frame)
    threshold : a cell moved when a channel differs from the background by more than this many grey levels ...
    relative : ... plus this share of the background's brightest channel there
    max_share : more cells moved than this share: the scene changed as a whole, no cue from that frame
    max_gap_s : frames farther apart than this (seconds), or a frame earlier than the one before: the background starts again
    margin_cells : a candidate is on moving cells when one lies within its radius plus this many cells
    regions : a full-frame search looks only in the boxes around the moving cells (:meth:`MotionCue.regions`; faster:
        on the simulated lab a full-frame frame set took half the time) while there are at most ``max_regions`` of them
        and they cover at most ``max_region_share`` of the frame; False = the whole frame is searched and the
        candidates where nothing moved dropped
    still_search_s : a camera's full-frame search ignores the cue (the whole frame, every candidate kept) when its last
        such search is at least this long ago (seconds; ``inf``: never): a ball lying still that was never followed
        (on the table before a serve, held still in front of the cameras) is found within this time
        (:meth:`MotionCue.whole_frame_due`)
    """

    cell_px: float = 4.0
    alpha: float = 0.1
    learn_every: int = 4
    threshold: float = 12.0
    relative: float = 0.15
    max_share: float = 0.3
    max_gap_s: float = 0.5
    margin_cells: int = 1
    regions: bool = True
    max_regions: int = 8
    max_region_share: float = 0.5
    still_search_s: float = 0.5

    def __post_init__(self):
        v = self.still_search_s
        if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) or not float(v) > 0:
            raise ValueError(f"MotionOptions.still_search_s must be a number of seconds > 0 (inf: never), got {v!r}")
        for name, lo, hi in (("alpha", 0.0, 1.0), ("max_share", 0.0, 1.0), ("max_region_share", 0.0, 1.0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) or not lo < float(v) <= hi:
                raise ValueError(f"MotionOptions.{name} must be a number in ({lo}, {hi}], got {v!r}")
        for name in ("threshold", "relative", "max_gap_s", "cell_px"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) or not (math.isfinite(v) and v >= 0):
                raise ValueError(f"MotionOptions.{name} must be a finite number >= 0, got {v!r}")
        if not isinstance(self.regions, (bool, np.bool_)):
            raise ValueError(f"MotionOptions.regions must be True or False, got {self.regions!r}")
        if not self.max_gap_s > 0:
            raise ValueError(f"MotionOptions.max_gap_s must be > 0 seconds, got {self.max_gap_s!r}")
        if not self.cell_px >= 1:
            raise ValueError(f"MotionOptions.cell_px must be >= 1 pixel, got {self.cell_px!r}")
        for name, lo in (("learn_every", 1), ("margin_cells", 0), ("max_regions", 1)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
                raise ValueError(f"MotionOptions.{name} must be an integer >= {lo}, got {v!r}")


def reduced_size(width: int, height: int, cell_px: float) -> tuple[int, int]:
    """``(cols, rows)`` of a ``width x height`` frame in cells of about ``cell_px`` pixels (at least 1 x 1)."""
    return max(1, int(round(width / cell_px))), max(1, int(round(height / cell_px)))


def sample_points(width: int, height: int, cols: int, rows: int) -> tuple[np.ndarray, np.ndarray]:
    """``(ys (rows,), xs (cols,))`` int64: the pixel at the centre of each cell of a ``width x height`` frame in
    ``cols x rows`` cells."""
    return (np.floor((np.arange(rows) + 0.5) * (height / rows)).astype(np.int64),
            np.floor((np.arange(cols) + 0.5) * (width / cols)).astype(np.int64))


def observe_reference(image: np.ndarray, ys: np.ndarray, xs: np.ndarray, bg: np.ndarray, threshold: float, relative: float,
                      alpha: float, mask: np.ndarray) -> int:
    """Steps 1, 2 and 4 of the module docstring, numpy: ``mask`` (rows, cols) bool := the cells of ``image`` (at
    ``ys`` x ``xs``) that moved against ``bg`` (rows, cols, 3) float32, then ``bg += alpha (cells - bg)`` (float32);
    returns the moving cells' count."""
    cells = image[np.ix_(ys, xs)].astype(np.float32)
    d = np.abs(cells - bg).max(axis=2)
    mask[...] = d > np.float32(threshold) + np.float32(relative) * bg.max(axis=2)
    bg += np.float32(alpha) * (cells - bg)
    return int(mask.sum())


@numba.njit(cache=True, nogil=True)
def _observe_nb(image, ys, xs, bg, threshold, relative, alpha, mask):
    count = 0
    for r in range(len(ys)):
        y = ys[r]
        for c in range(len(xs)):
            x = xs[c]
            v0, v1, v2 = np.float32(image[y, x, 0]), np.float32(image[y, x, 1]), np.float32(image[y, x, 2])
            b0, b1, b2 = bg[r, c, 0], bg[r, c, 1], bg[r, c, 2]
            d = max(abs(v0 - b0), abs(v1 - b1), abs(v2 - b2))
            level = max(b0, b1, b2)
            bg[r, c, 0] = b0 + alpha * (v0 - b0)
            bg[r, c, 1] = b1 + alpha * (v1 - b1)
            bg[r, c, 2] = b2 + alpha * (v2 - b2)
            m = d > threshold + relative * level
            mask[r, c] = m
            count += m
    return count


def observe_cells(image: np.ndarray, ys: np.ndarray, xs: np.ndarray, bg: np.ndarray, threshold: float, relative: float,
                  alpha: float, mask: np.ndarray) -> int:
    """:func:`observe_reference` compiled (numba): the same mask, background and count."""
    return int(_observe_nb(image, ys, xs, bg, np.float32(threshold), np.float32(relative), np.float32(alpha), mask))


class MotionCue:
    """One fixed camera's background and the cells of its newest frame that moved (module docstring).

    width, height : the camera's image size, pixels; options : :class:`MotionOptions`
    After :meth:`observe` with ``need_mask``, ``mask`` is the (rows, cols) bool array of moving cells, or None
    where the frame gave no cue (the first frame, after a gap, a change of the whole scene).
    """

    def __init__(self, width: int, height: int, options: MotionOptions | None = None):
        self.options = MotionOptions() if options is None else options
        if not isinstance(self.options, MotionOptions):
            raise ValueError(f"options must be a MotionOptions, got {type(options).__name__}")
        self.size_wh = (int(width), int(height))
        self.cells_wh = reduced_size(width, height, self.options.cell_px)
        self.scale = (width / self.cells_wh[0], height / self.cells_wh[1])  # camera pixels per cell, x and y
        self._ys, self._xs = sample_points(width, height, *self.cells_wh)
        self._bg = np.zeros((self.cells_wh[1], self.cells_wh[0], 3), np.float32)
        self._mask = np.zeros((self.cells_wh[1], self.cells_wh[0]), bool)
        self.reset()

    def reset(self) -> None:
        """Forget the background (the next frame starts it again)."""
        self._has_bg = False
        self._last_t: float | None = None
        self._frame = None  # the frame number last observed, and whether its cells were looked at
        self._seen = False
        self._count = 0
        self._last_whole: float | None = None  # when a full-frame search last ignored the cue
        self.mask: np.ndarray | None = None

    def observe(self, image: np.ndarray, t_s: float = math.nan, *, frame=None, need_mask: bool = False) -> np.ndarray | None:
        """Take the camera's next frame ((H, W, 3) uint8 of its size, trusted) at time ``t_s`` (NaN: unknown);
        ``frame`` a number of the frame set (a second call with the same number, to ask for the mask after a
        window search, does not count the frame twice). With ``need_mask``: returns ``mask`` (None: no cue)."""
        o = self.options
        again = frame is not None and frame == self._frame
        if not again:
            if self._last_t is not None and math.isfinite(t_s) and not -1e-9 <= t_s - self._last_t <= o.max_gap_s:
                self._has_bg = False  # a gap, or the clock went back (1 ns: frame stamps in floats)
            if math.isfinite(t_s):
                self._last_t = t_s
            self._frame, self._seen = frame, False
            self._count += 1
            self.mask = None
        if self._seen or not (need_mask or self._count % o.learn_every == 0 or not self._has_bg):
            return self.mask if need_mask else None  # (this frame's cue is known, or not asked for)
        self._seen = True
        if not self._has_bg:
            self._restart(image, t_s)
            return None
        n = observe_cells(image, self._ys, self._xs, self._bg, o.threshold, o.relative, o.alpha, self._mask)  # against the frames before
        if n > o.max_share * self._mask.size:
            self._restart(image, t_s)  # the whole scene changed: it is the background now
            return None
        self.mask = self._mask
        return self.mask if need_mask else None

    def _restart(self, image, t_s: float) -> None:
        self._bg[...] = image[np.ix_(self._ys, self._xs)]
        self._has_bg = True
        self.mask = None
        if math.isfinite(t_s):  # a frame without a cue: what a full-frame search of it finds is not gated
            self._last_whole = t_s

    def whole_frame_due(self, t_s: float) -> bool:
        """For a full-frame search of the frame observed at ``t_s``: whether it ignores the cue (the whole frame, every
        candidate kept): when the frame gives no cue, or the last such search (or the last frame without a cue: the
        background's start) is ``still_search_s`` or more ago (or later than ``t_s``: the clock went back); the time is
        then remembered. A frame of unknown time (NaN) is searched by the cue, when there is one."""
        if self.mask is None:  # no cue: the background (re)started on this frame, which :meth:`_restart` remembered
            return True
        if not (math.isfinite(t_s) and math.isfinite(self.options.still_search_s)):
            return False
        last = self._last_whole
        if last is None or t_s - last >= self.options.still_search_s - 1e-9 or t_s < last:  # (1 ns: frame stamps in floats)
            self._last_whole = t_s
            return True
        return False

    def regions(self, margin_px: float):
        """The boxes ``(x0, y0, x1, y1)`` (camera pixels, integers, inside the image) around the moving cells, each
        grown by ``margin_px`` (a ball's radius: its centre may lie off the cells its edge moved) and merged where
        they touch: where a full-frame search needs to look. None without a cue, with ``regions`` off, or when the boxes would cover more
        than ``max_region_share`` of the frame or number more than ``max_regions`` (then the full frame is
        cheaper); an empty list when nothing moved."""
        o = self.options
        if self.mask is None or not o.regions:
            return None
        sx, sy = self.scale
        mx, my = int(math.ceil(margin_px / sx)), int(math.ceil(margin_px / sy))
        grown = cv2.dilate(self.mask.view(np.uint8), np.ones((2 * my + 1, 2 * mx + 1), np.uint8))
        n, _, stats, _ = cv2.connectedComponentsWithStats(grown, connectivity=8)
        if n - 1 > o.max_regions:
            return None
        w, h = self.size_wh
        boxes, area = [], 0
        for c0, r0, cw, ch, _ in stats[1:]:
            x0, y0 = max(int(math.floor(c0 * sx)), 0), max(int(math.floor(r0 * sy)), 0)
            x1, y1 = min(int(math.ceil((c0 + cw) * sx)), w), min(int(math.ceil((r0 + ch) * sy)), h)
            boxes.append((x0, y0, x1, y1))
            area += (x1 - x0) * (y1 - y0)
        return None if area > o.max_region_share * w * h else boxes

    def moved(self, uv_px: np.ndarray, diameters_px: np.ndarray) -> np.ndarray:
        """(n,) bool: the candidates at ``uv_px`` (n, 2) of ``diameters_px`` (n,) on moving cells (all True
        without a cue; a candidate with a non-finite centre or diameter: False when there is a cue)."""
        uv = np.asarray(uv_px, np.float64).reshape(-1, 2)
        d = np.asarray(diameters_px, np.float64).reshape(-1)
        if self.mask is None:
            return np.ones(len(uv), bool)
        out = np.zeros(len(uv), bool)
        rows, cols = self.mask.shape
        sx, sy = self.scale
        m = self.options.margin_cells
        for i in range(len(uv)):
            u, v, dd = uv[i, 0], uv[i, 1], d[i]
            if not (math.isfinite(u) and math.isfinite(v) and math.isfinite(dd)):
                continue
            cu, cv = (u + 0.5) / sx, (v + 0.5) / sy  # cell coordinates (cell c spans [c, c + 1))
            ru, rv = 0.5 * max(dd, 0.0) / sx + m, 0.5 * max(dd, 0.0) / sy + m
            c0, c1 = max(int(math.floor(cu - ru)), 0), min(int(math.floor(cu + ru)) + 1, cols)
            r0, r1 = max(int(math.floor(cv - rv)), 0), min(int(math.floor(cv + rv)) + 1, rows)
            out[i] = c0 < c1 and r0 < r1 and bool(self.mask[r0:r1, c0:c1].any())
        return out


class CameraCues:
    """The motion cues of several fixed cameras' frame sequences, one :class:`MotionCue` per key (a camera's name and
    image size, say), made on the key's first frame: what a sequence of labelled or recorded frames searched offline
    needs (``rt2 eval detector --motion-cue``, ``rt2 label --motion-cue``)."""

    def __init__(self, options: MotionOptions | None = None):
        self.options = options
        self.cues: dict = {}

    def __contains__(self, key) -> bool:
        return key in self.cues

    def __len__(self) -> int:
        return len(self.cues)

    def _cue(self, key, image: np.ndarray) -> MotionCue:
        cue = self.cues.get(key)
        if cue is None:
            cue = self.cues[key] = MotionCue(image.shape[1], image.shape[0], self.options)
        return cue

    def warm(self, key, image: np.ndarray, t_s: float = math.nan) -> None:
        """Show ``key``'s camera a frame before the ones searched (its background; nothing is asked of it)."""
        self._cue(key, image).observe(image, t_s, need_mask=True)

    def observe(self, key, image: np.ndarray, t_s: float = math.nan) -> MotionCue | None:
        """Show ``key``'s camera its next frame; returns its cue where that gates this frame's candidates
        (:meth:`MotionCue.moved`), None where the frame is searched without it (no cue, or a still ball's turn:
        :meth:`MotionCue.whole_frame_due`)."""
        cue = self._cue(key, image)
        cue.observe(image, t_s, need_mask=True)
        return None if cue.whole_frame_due(t_s) else cue


key_cache_on_callees(globals())  # an edit of a helper or a constant recompiles the kernels
