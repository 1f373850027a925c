"""A contact sheet of what the ball detector gets wrong on labelled images, drawn by ``rt2 eval detector --figure``.

Two kinds of tile, each a crop of the image around the failure, enlarged, with the label's box in green
and the detector's boxes in red (its first candidate) and orange (its other top-K candidates):

* **miss**: a labelled ball (at least ``min_diameter_px`` wide) that no top-K candidate hits, so the
  tracker cannot see it in that camera;
* **false alarm**: the detector's first candidate lies off every labelled ball (in an image with or
  without a ball), so that camera reports something else as the ball.

"Hits" is ``rt2 eval detector``'s rule (scores.py): within one ball diameter of the labelled centre.
Tiles are in image order, misses first; at most ``max_tiles`` are drawn and the header says how many of each
there were. A miss in an image where the detector had no candidate at all says "no detection" on its tile.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["Failure", "contact_sheet", "find_failures"]

_GREEN, _RED, _ORANGE = (40, 220, 40), (255, 40, 40), (255, 170, 0)  # RGB


@dataclass(frozen=True)
class Failure:
    """kind : "miss" or "false alarm"; image : index into the labelled images; center_px : (u, v) rt2 pixels
    the tile is centred on (the ball's centre, or the false detection's); diameter_px : the ball's (0 for a false alarm)"""

    kind: str
    image: int
    center_px: tuple
    diameter_px: float


def find_failures(labelled, candidates_uv, *, min_diameter_px: float = 6.0) -> list[Failure]:
    """Misses and false alarms (module docstring).

    labelled : LabelledImage list; candidates_uv : per image the (k, 2) top-K candidate centres, best first
    """
    from harness.experiments.detector.scores import truth_of

    misses, alarms = [], []
    for i, (li, uv) in enumerate(zip(labelled, candidates_uv)):
        c, d = truth_of(li)
        uv = np.asarray(uv, float).reshape(-1, 2)
        uv = uv[np.isfinite(uv).all(axis=1)]
        dist = np.linalg.norm(uv[:, None, :] - c[None, :, :], axis=2)  # (k, g)
        near = dist <= d[None, :]  # within two radii: the rule of scores.score_detections
        for j in np.flatnonzero(d >= min_diameter_px):
            if not near[:, j].any():
                misses.append(Failure("miss", i, (float(c[j, 0]), float(c[j, 1])), float(d[j])))
        if len(uv) and not near[0].any():
            alarms.append(Failure("false alarm", i, (float(uv[0, 0]), float(uv[0, 1])), 0.0))
    return misses + alarms


def contact_sheet(labelled, candidates_uv, candidates_boxes, path, *, min_diameter_px: float = 6.0, max_tiles: int = 48,
                  columns: int = 8, tile_px: int = 160, load=None) -> tuple[Path, int, int]:
    """Draw the contact sheet to ``path`` (PNG); returns (path, misses, false alarms).

    candidates_uv : per image the (k, 2) top-K candidate centres, rt2 pixels, best first
    candidates_boxes : per image their (k, 4) boxes ``[x, y, w, h]`` px
    load : image index -> the (H, W, 3) RGB image the candidates were found on (default: the labelled file as it is;
        e.g. the frame with its balls painted out for ``rt2 eval detector --ball-free``)
    """
    import cv2

    from harness.common.outputs import atomic_path
    from harness.experiments.detector.train import load_image

    boxes = [np.asarray(b, float).reshape(-1, 4) for b in candidates_boxes]
    failures = find_failures(labelled, candidates_uv, min_diameter_px=min_diameter_px)
    n_miss = sum(f.kind == "miss" for f in failures)
    n_alarm = len(failures) - n_miss
    n_balls = sum(int(np.sum(np.minimum(li.boxes_xywh[:, 2], li.boxes_xywh[:, 3]) >= min_diameter_px)) for li in labelled)
    shown = failures[:max_tiles]
    cache: dict = {}
    tiles = []
    for f in shown:
        if f.image not in cache:
            cache = {f.image: load_image(labelled[f.image]) if load is None else load(f.image)}  # tiles in image order: one image in memory
        tiles.append(_tile(cache[f.image], labelled[f.image], boxes[f.image], f, tile_px))
    caption_h = 34
    cols = max(1, min(columns, len(tiles)))
    rows = -(-len(tiles) // cols) if tiles else 0
    header = [f"rt2 eval detector: {n_miss} misses of {n_balls} balls >= {min_diameter_px:g} px (no top-K candidate on the ball),",
              f"{n_alarm} false alarms (first candidate off every ball) in {len(labelled)} images"
              + (f"; showing the first {len(shown)}" if len(shown) < len(failures) else ""),
              "green: label   red: first candidate   orange: other candidates"]
    width = max(cols * tile_px, 760)
    sheet = np.full((22 * len(header) + 10 + rows * (tile_px + caption_h), width, 3), 255, np.uint8)
    for k, line in enumerate(header):
        cv2.putText(sheet, line, (6, 20 + 22 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    top = 22 * len(header) + 10
    for k, (f, tile) in enumerate(zip(shown, tiles)):
        r, c = divmod(k, cols)
        y0, x0 = top + r * (tile_px + caption_h), c * tile_px
        sheet[y0 : y0 + tile_px, x0 : x0 + tile_px] = tile
        colour = (200, 0, 0) if f.kind == "miss" else (0, 0, 200)
        label = f"{f.kind}" + (f" d={f.diameter_px:.0f}px" if f.kind == "miss" else "")
        cv2.putText(sheet, label, (x0 + 4, y0 + tile_px + 13), cv2.FONT_HERSHEY_SIMPLEX, 0.42, colour, 1, cv2.LINE_AA)
        name = Path(labelled[f.image].path).name
        name = name if len(name) <= 24 else name[:11] + ".." + name[-11:]
        cv2.putText(sheet, name, (x0 + 4, y0 + tile_px + 28), cv2.FONT_HERSHEY_SIMPLEX, 0.36, (60, 60, 60), 1, cv2.LINE_AA)
    path = Path(path)
    with atomic_path(path, "--figure") as tmp:  # never a half-written figure
        if not cv2.imwrite(str(tmp), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR)):
            raise ValueError(f"cannot write the contact sheet to {str(path)!r} (use .png; or the disk is full)")
    return path, n_miss, n_alarm


def _tile(image: np.ndarray, li, boxes: np.ndarray, f: Failure, tile_px: int) -> np.ndarray:
    """A ``tile_px`` square: the crop around ``f`` (side 4 ball diameters, at least 48 px), boxes drawn at tile scale."""
    import cv2

    side = int(np.clip(4 * max(f.diameter_px, float(np.min(li.boxes_xywh[:, 2:], initial=12.0))), 48, 400))
    u, v = (int(round(a)) for a in f.center_px)
    x0, y0 = u - side // 2, v - side // 2
    pad = cv2.copyMakeBorder(image, side, side, side, side, cv2.BORDER_CONSTANT, value=(90, 90, 90))
    crop = pad[y0 + side : y0 + 2 * side, x0 + side : x0 + 2 * side]
    scale = tile_px / side
    tile = cv2.resize(crop, (tile_px, tile_px), interpolation=cv2.INTER_NEAREST if scale >= 1 else cv2.INTER_AREA)

    def rect(b, colour, thick):
        x, y, w, h = ((np.asarray(b, float) - [x0, y0, 0, 0]) * scale).tolist()
        cv2.rectangle(tile, (int(round(x)) - 1, int(round(y)) - 1), (int(round(x + w)), int(round(y + h))), colour, thick)

    for b in li.boxes_xywh:
        rect(b, _GREEN, 2)
    for k, b in enumerate(boxes):
        rect(b, _RED if k == 0 else _ORANGE, 2 if k == 0 else 1)
    if not len(boxes):  # nothing to draw would look like a drawing that failed: say it
        cv2.putText(tile, "no detection", (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(tile, "no detection", (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 0), 1, cv2.LINE_AA)
    return tile
