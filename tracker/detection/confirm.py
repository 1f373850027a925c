"""The learned stage's second look at a whole frame: a small CNN on each candidate's crop at the ball's scale.

The heatmap network (:mod:`tracker.detection.learned`) scores every cell of a frame with ~10k weights and a
receptive field of ~120 px: on cameras it never saw, a ceiling lamp, an elbow or a loudspeaker's glint can
outrank the ball. The confirmation network looks again at the few best candidates of a whole frame: each one's
crop of ``context`` times its diameter (at least ``min_side_px``), resampled to ``crop_px`` pixels (the ball
about ``crop_px / context`` pixels across whatever its size: what it learns is the ball's shape against its
surroundings); its output is a probability that the candidate is a ball, and the candidate's score becomes the
geometric mean of it and the heat (``sqrt(p * heat)``: two looks that must both find a ball; on held-out frames the
mean kept the heat's few alarms on ball-free frames where the confirmation's probability alone raised them, and
the confirmation sees the crop alone, not the heat, so the two are separate evidence: README Results). It runs on
the candidates of whole frames only (single images, the label page's proposals, ``rt2 label --auto``'s frame sets); a
window keeps the heat, and so does a live tracker, whose cameras report the heat's candidates (the consensus of the
cameras rejects a camera's false alarms there; eight cameras' full frames confirmed cost ~1.4 ms each).

With a second context (``ConfirmNet.context2``) each candidate is cut out twice, at two scales (the white file: 6
and 2 diameters, the ball ~8 and ~24 px across: its surroundings, and the ball itself), and the graph takes both
crops stacked as six channels (:func:`stacked_crop`); its graph is two networks, one on each crop, their
probabilities averaged
(on cameras the networks never saw, the two scales are wrong on different things: README Results).

Inference: ONNX Runtime on the CPU, one thread, a session per thread (as the heatmap network); the graph takes
``crops`` ``(n, P, P, 3)`` uint8 RGB (``(n, P, P, 6)`` with a second crop) and gives ``p`` ``(n,)``. The crop is
:func:`confirm_crop`, the same function in training (``harness/experiments/detector/confirm_train.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from checks.per_thread import PerThread
from tracker.detection.onnx_session import SessionFactory

__all__ = ["ConfirmNet", "CONFIRM_FIELDS", "confirm_crop", "stacked_crop"]

#: the model file's fields of the confirmation network (all or none; with a learned stage only)
CONFIRM_FIELDS = ("learned_confirm_onnx", "learned_confirm_geometry")


def confirm_crop(image: np.ndarray, u: float, v: float, d: float, context: float, crop_px: int, min_side_px: float) -> np.ndarray:
    """The ``crop_px`` x ``crop_px`` uint8 crop of ``image`` (H, W, 3) around the candidate at ``(u, v)`` (rt2 pixels)
    of diameter ``d``: a square of ``max(context * d, min_side_px)`` image pixels (whole pixels, the border
    reflected where it leaves the image) resampled with area averaging (``cv2.INTER_AREA``; enlarged bilinearly)."""
    h, w = image.shape[:2]
    side = max(float(context) * float(d), float(min_side_px))
    n = max(2, int(round(side)))
    x0 = int(math.floor(u + 0.5 - n / 2.0))
    y0 = int(math.floor(v + 0.5 - n / 2.0))
    x1, y1 = x0 + n, y0 + n
    cx0, cy0, cx1, cy1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    if cx0 >= cx1 or cy0 >= cy1:  # wholly outside: nothing of the frame to look at
        return np.zeros((crop_px, crop_px, 3), np.uint8)
    part = image[cy0:cy1, cx0:cx1]
    if (cx0, cy0, cx1, cy1) != (x0, y0, x1, y1):
        mode = cv2.BORDER_REFLECT_101 if min(part.shape[:2]) > 1 else cv2.BORDER_REPLICATE
        part = cv2.copyMakeBorder(part, cy0 - y0, y1 - cy1, cx0 - x0, x1 - cx1, mode)
    interp = cv2.INTER_AREA if n >= crop_px else cv2.INTER_LINEAR
    return cv2.resize(np.ascontiguousarray(part), (crop_px, crop_px), interpolation=interp)


def stacked_crop(image: np.ndarray, u: float, v: float, d: float, contexts, crop_px: int, min_side_px: float) -> np.ndarray:
    """``(crop_px, crop_px, 3 * len(contexts))`` uint8: :func:`confirm_crop` of the candidate at each context, stacked
    along the channels in that order (what a confirmation network of one or two crops takes; training cuts its examples
    with it too)."""
    one = [confirm_crop(image, u, v, d, c, crop_px, min_side_px) for c in contexts]
    return one[0] if len(one) == 1 else np.concatenate(one, axis=2)


@dataclass(frozen=True, eq=False)
class ConfirmNet:
    """The confirmation network of a learned stage (module docstring).

    onnx : the network, ONNX bytes (input ``crops`` (n, P, P, :attr:`channels`) uint8; output ``p`` (n,))
    crop_px : P, the side of the crops it takes
    context : a crop's side in candidate diameters
    min_side_px : a crop's side at least, image pixels (both crops)
    candidates : the heat's best candidates of a frame it looks at (at most)
    gate : heat probability a candidate needs to be looked at
    threshold : the single image's operating point on the candidates' scores (``sqrt(p * heat)``), chosen by
        training; the stage's own ``threshold`` stays the heat's (windows, and a whole frame without the second look)
    description : how and on what it was trained
    context2 : None (one crop), or a second crop's side in candidate diameters: the network takes both crops, stacked
        as six channels (``(n, P, P, 6)``: the first crop's RGB, then the second's), and sees the ball's
        surroundings and the ball itself at two scales
    """

    onnx: bytes = field(repr=False)
    crop_px: int = 48
    context: float = 6.0
    min_side_px: float = 48.0
    candidates: int = 6
    gate: float = 0.05
    threshold: float = 0.5
    description: str = ""
    context2: float | None = None

    def __post_init__(self):
        where = "ConfirmNet"
        if not isinstance(self.onnx, (bytes, bytearray)) or len(self.onnx) < 16:
            raise ValueError(f"{where}: onnx must be the network's ONNX bytes, got {type(self.onnx).__name__}")
        for name, lo, hi in (("crop_px", 8, 256), ("candidates", 1, 64)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not lo <= v <= hi:
                raise ValueError(f"{where}: {name} must be an integer in [{lo}, {hi}], got {v!r}")
            object.__setattr__(self, name, int(v))
        for name, lo, hi in (("context", 1.0, 32.0), ("min_side_px", 2.0, 4096.0), ("context2", 1.0, 32.0)):
            v = getattr(self, name)
            if name == "context2" and v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)) or not (math.isfinite(v) and lo <= v <= hi):
                raise ValueError(f"{where}: {name} must be " + ("None or " if name == "context2" else "") + f"a number in [{lo:g}, {hi:g}], got {v!r}")
            object.__setattr__(self, name, float(v))
        for name in ("gate", "threshold"):
            g = getattr(self, name)
            if isinstance(g, bool) or not isinstance(g, (int, float, np.floating)) or not 0.0 < float(g) < 1.0:
                raise ValueError(f"{where}: {name} must be a probability in (0, 1), got {g!r}")
            object.__setattr__(self, name, float(g))
        object.__setattr__(self, "onnx", bytes(self.onnx))
        object.__setattr__(self, "_sessions", PerThread(SessionFactory(self.onnx)))

    @property
    def contexts(self) -> tuple[float, ...]:
        """The crops' sides in candidate diameters: ``(context,)`` or ``(context, context2)``."""
        return (self.context,) if self.context2 is None else (self.context, self.context2)

    @property
    def channels(self) -> int:
        """The crops' channels: 3, or 6 with a second crop (``context2``)."""
        return 3 * len(self.contexts)

    def crops(self, image: np.ndarray, uv, d) -> np.ndarray:
        """(n, P, P, :attr:`channels`) uint8: :func:`stacked_crop` of each candidate."""
        out = np.empty((len(uv), self.crop_px, self.crop_px, self.channels), np.uint8)
        for i, ((u, v), di) in enumerate(zip(np.asarray(uv, np.float64).reshape(-1, 2), np.asarray(d, np.float64).reshape(-1))):
            out[i] = stacked_crop(image, u, v, di, self.contexts, self.crop_px, self.min_side_px)
        return out

    def probabilities(self, crops: np.ndarray) -> np.ndarray:
        """(n,) float64 ball probabilities of ``crops`` (n, P, P, :attr:`channels`) uint8."""
        if len(crops) == 0:
            return np.zeros(0)
        p = self._sessions.get().run(None, {"crops": np.ascontiguousarray(crops, np.uint8)})[0]
        return np.asarray(p, np.float64).reshape(-1)

    def rescore(self, image: np.ndarray, uv, heat, d) -> np.ndarray:
        """(n,) each candidate's score: ``sqrt(p * heat)``, ``p`` the confirmation's probability (``uv`` (n, 2), heat
        probabilities (n,), diameters (n,))."""
        heat = np.asarray(heat, np.float64).reshape(-1)
        return np.sqrt(self.probabilities(self.crops(image, uv, d)) * heat)

    # -- files -----------------------------------------------------------------------------------
    def to_fields(self) -> dict:
        geo = [self.crop_px, self.context, self.min_side_px, self.candidates, self.gate, self.threshold]
        return dict(learned_confirm_onnx=np.frombuffer(self.onnx, np.uint8),
                    learned_confirm_geometry=np.array(geo + ([] if self.context2 is None else [self.context2]), np.float64),
                    learned_confirm_description=np.array(self.description))

    @classmethod
    def from_fields(cls, data: dict, src: str) -> "ConfirmNet | None":
        """The confirmation network stored in a model file's fields, or None when the file has none."""
        present = [k for k in CONFIRM_FIELDS if k in data]
        if not present:
            return None
        missing = [k for k in CONFIRM_FIELDS if k not in data]
        if missing:
            raise ValueError(f"{src}: confirmation network fields incomplete, missing {missing}")
        onnx, geo = data["learned_confirm_onnx"], data["learned_confirm_geometry"]
        if onnx.dtype != np.uint8 or onnx.ndim != 1:
            raise ValueError(f"{src}: field 'learned_confirm_onnx' must be the ONNX bytes as a uint8 vector, got dtype {onnx.dtype} shape {onnx.shape}")
        if geo.dtype.kind not in "biuf" or geo.shape not in ((6,), (7,)) or not np.isfinite(geo).all() or not float(geo[0]).is_integer() or not float(geo[3]).is_integer():
            raise ValueError(f"{src}: field 'learned_confirm_geometry' must be [crop px, context, min side px, candidates, gate, threshold] "
                             f"and optionally a second crop's context (integers, numbers, probabilities), got {geo!r}")
        desc = data.get("learned_confirm_description", np.array(""))
        if desc.dtype.kind != "U":
            raise ValueError(f"{src}: field 'learned_confirm_description' must be a string, got dtype {desc.dtype}")
        try:
            net = cls(onnx.tobytes(), crop_px=int(geo[0]), context=float(geo[1]), min_side_px=float(geo[2]), candidates=int(geo[3]),
                      gate=float(geo[4]), threshold=float(geo[5]), description=str(desc), context2=float(geo[6]) if geo.shape == (7,) else None)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{src}: {exc}") from None
        problem = net.check()
        if problem:
            raise ValueError(f"{src}: field 'learned_confirm_onnx': {problem}")
        return net

    def check(self) -> str | None:
        """None when the network loads and maps two crops to two probabilities; else what is wrong."""
        try:
            p = self.probabilities(np.zeros((2, self.crop_px, self.crop_px, self.channels), np.uint8))
        except Exception as exc:  # a damaged graph or the wrong inputs: ONNX Runtime's own message, on one line
            return f"not a confirmation network this rt2 can run ({type(exc).__name__}: {str(exc).splitlines()[0][:200] if str(exc) else ''})"
        if p.shape != (2,):
            return f"the network maps 2 crops to shape {p.shape}, expected (2,)"
        if not (np.isfinite(p).all() and ((p >= 0) & (p <= 1)).all()):
            return "the network's output is not a probability"
        return None

