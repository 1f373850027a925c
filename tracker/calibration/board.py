"""ChArUco boards: the spec, OpenCV's board object, and corner detection in one image.

A board of ``columns x rows`` chessboard squares of side ``square_m`` carries ArUco markers of
side ``marker_m`` in its white squares. Its inner chessboard corners, ``(columns-1) x (rows-1)``
of them, are the calibration points; OpenCV numbers them row by row and places corner ``i`` at
``((i % (columns-1) + 1) * square_m, (i // (columns-1) + 1) * square_m, 0)`` in the board frame
(``CharucoBoard.getChessboardCorners``). Pixels follow rt2 (and OpenCV): (0, 0) is the centre of
the top-left pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from checks.arrays import describe

__all__ = ["BoardSpec", "CharucoCorners", "board_from_dict", "detect_charuco"]


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board.

    columns, rows : number of chessboard squares across and down (>= 3 each)
    square_m : side of a chessboard square, metres
    marker_m : side of an ArUco marker, metres (< square_m)
    dictionary : OpenCV predefined dictionary name, e.g. ``"DICT_4X4_1000"``
    inverted : the board is printed white-on-black (detect on the inverted image)
    legacy_pattern : OpenCV's pre-4.6 layout (even row counts start with a marker)
    """

    columns: int
    rows: int
    square_m: float
    marker_m: float
    dictionary: str = "DICT_4X4_50"
    inverted: bool = False
    legacy_pattern: bool = False

    def __post_init__(self):
        for name in ("columns", "rows"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 3:
                raise ValueError(f"board {name} must be an integer >= 3, got {v!r}")
        if not (np.isfinite(self.square_m) and self.square_m > 0):
            raise ValueError(f"board square_m must be a positive length in metres, got {self.square_m!r}")
        if not (np.isfinite(self.marker_m) and 0 < self.marker_m < self.square_m):
            raise ValueError(f"board marker_m must be in (0, square_m={self.square_m}), got {self.marker_m!r}")
        if not (isinstance(self.dictionary, str) and self.dictionary.startswith("DICT_") and hasattr(cv2.aruco, self.dictionary)):
            valid = sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_"))
            raise ValueError(f"unknown ArUco dictionary {self.dictionary!r}; valid: {valid}")
        n_markers = (self.columns * self.rows) // 2
        size = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary)).bytesList.shape[0]
        if n_markers > size:
            raise ValueError(f"board of {self.columns}x{self.rows} squares needs {n_markers} markers; {self.dictionary} has {size}")

    @property
    def n_corners(self) -> int:
        return (self.columns - 1) * (self.rows - 1)

    @property
    def corners_board_m(self) -> np.ndarray:
        """(n_corners, 3) inner corners in the board frame (z = 0), metres, OpenCV's order."""
        return np.asarray(self.cv_board().getChessboardCorners(), float).reshape(-1, 3)

    @property
    def size_m(self) -> tuple[float, float]:
        """(width, height) of the board's printed squares, metres."""
        return self.columns * self.square_m, self.rows * self.square_m

    def cv_board(self) -> "cv2.aruco.CharucoBoard":
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        board = cv2.aruco.CharucoBoard((self.columns, self.rows), self.square_m, self.marker_m, d)
        board.setLegacyPattern(bool(self.legacy_pattern))
        return board


_INCH_M = 0.0254
_UNITS_M = {"m": 1.0, "metre": 1.0, "meter": 1.0, "cm": 0.01, "mm": 0.001, "inch": _INCH_M, "in": _INCH_M}


def board_from_dict(data: dict, *, source: str = "board") -> BoardSpec:
    """Board spec from a mapping: rt2's own keys or caliscope's ``charuco.toml``.

    rt2: ``columns, rows, square_m, marker_m, dictionary[, inverted, legacy_pattern]``.
    caliscope: ``columns, rows, dictionary, aruco_scale, square_size_override_cm`` (or
    ``board_width/board_height`` with ``units``), ``inverted, legacy_pattern``.
    """
    if not isinstance(data, dict):
        raise ValueError(f"{source}: expected a mapping, got {describe(data)}")
    for key in ("columns", "rows"):
        if key not in data:
            raise ValueError(f"{source}: missing field {key!r}")
    kw = {"inverted": bool(data.get("inverted", False)), "legacy_pattern": bool(data.get("legacy_pattern", False))}
    if "dictionary" in data:
        kw["dictionary"] = str(data["dictionary"])
    try:
        cols, rows = int(data["columns"]), int(data["rows"])
        if "square_m" in data:
            square = float(data["square_m"])
            if "marker_m" not in data:
                raise ValueError("missing field 'marker_m'")
            marker = float(data["marker_m"])
        elif "square_size_override_cm" in data or "board_width" in data:
            if data.get("square_size_override_cm"):
                square = float(data["square_size_override_cm"]) * 0.01
            else:
                unit = str(data.get("units", "m"))
                if unit not in _UNITS_M:
                    raise ValueError(f"unknown units {unit!r}; valid: {sorted(_UNITS_M)}")
                w, h = float(data["board_width"]) * _UNITS_M[unit], float(data["board_height"]) * _UNITS_M[unit]
                square = min(w / cols, h / rows)
            marker = square * float(data.get("aruco_scale", 0.75))
        else:
            raise ValueError("needs 'square_m' and 'marker_m' (or caliscope's 'square_size_override_cm' and 'aruco_scale')")
        return BoardSpec(cols, rows, square, marker, **kw)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{source}: {exc}") from None


@dataclass(frozen=True)
class CharucoCorners:
    """Corners found in one image.

    ids : (N,) corner ids (rows of ``BoardSpec.corners_board_m``)
    uv : (N, 2) pixels, sub-pixel refined
    n_markers : ArUco markers found (0: the board is not in the image)
    """

    ids: np.ndarray
    uv: np.ndarray
    n_markers: int

    def __len__(self) -> int:
        return len(self.ids)


def detect_charuco(image: np.ndarray, spec: BoardSpec, detector=None) -> CharucoCorners:
    """Find the board's inner corners in one image (uint8 gray (H, W) or RGB/BGR (H, W, 3)).

    ``detector`` : an optional ``cv2.aruco.CharucoDetector`` for ``spec`` made once
    (:func:`make_detector`) and reused over many images.
    """
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.ndim not in (2, 3):
        raise ValueError(f"image must be a uint8 (H, W) or (H, W, 3) array, got {describe(image)}")
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if spec.inverted:
        gray = 255 - gray
    det = detector if detector is not None else make_detector(spec)
    cc, ci, mc, mi = det.detectBoard(gray)
    n_markers = 0 if mi is None else len(mi)
    if ci is None or len(ci) == 0:
        return CharucoCorners(np.zeros(0, int), np.zeros((0, 2)), n_markers)
    return CharucoCorners(np.asarray(ci, int).ravel(), np.asarray(cc, float).reshape(-1, 2), n_markers)


def make_detector(spec: BoardSpec) -> "cv2.aruco.CharucoDetector":
    """An OpenCV ChArUco detector for ``spec`` (make once, reuse per image)."""
    params = cv2.aruco.CharucoParameters()
    params.minMarkers = 1
    return cv2.aruco.CharucoDetector(spec.cv_board(), params)
