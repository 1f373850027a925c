"""The single-convolution ball segmentation model (paper section 2.1, figure "single convolutional unit").

One 5x5 convolution over the RGB image plus a bias gives each pixel's ball *logit*; the sigmoid of
it is the ball probability image ``B`` of Algorithm 1. The model is constant after training and
loads from a small ``.npz`` file (no pickle).

Conventions:

* ``kernel[i, j, c]`` multiplies input pixel ``(row + i - 2, col + j - 2)``, channel ``c`` in
  ``colour_order``: a *correlation*, exactly what ``cv2.filter2D`` and ``torch.nn.Conv2d`` compute.
* The input is transformed per channel before the convolution:
  ``x = input_scale * T(pixel) + input_offset`` (channels in ``colour_order``) with
  ``T(p) = p`` (``input_transform="linear"``, the paper's raw RGB) or ``T(p) = log(p + log_offset_dn)``
  (``"log"``: a filter whose channel weights cancel is then blind to exposure and shading, so it
  tests chromaticity; a per-channel 256-entry lookup table at run time). Scale and offset are folded
  into an effective kernel and bias at construction, so inference is one 5x5x3 correlation of ``T`` of
  the raw channels (a compiled pass, ``tracker/detection/_correlate.py``, with its numpy reference).
* Borders are reflected without repeating the edge pixel (``cv2.BORDER_REFLECT_101``, which is
  ``padding_mode="reflect"`` in torch).
* The sigmoid is monotonic, so a threshold ``T`` on the probability equals the threshold
  ``log(T / (1 - T))`` on the logit: Algorithm 1 runs on logits and the full-frame sigmoid is skipped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from checks.arrays import describe
from checks.files import load_npz_checked
from tracker.detection._correlate import (coarse_kernel, coarse_logits, coarse_scratch_shape, correlate_5x5x3, correlate_5x5x3_blocks,
                                          scratch_shape)
from tracker.detection.learned import LearnedStage
from tracker.detection.verifier import CandidateVerifier
from tracker.images import check_image

__all__ = ["BallSegmentationModel", "INPUT_TRANSFORMS", "KERNEL_SIZE", "LogitWorkspace", "MODEL_FORMAT", "MODEL_VERSION", "logit", "sigmoid", "transform_lut"]

KERNEL_SIZE = 5  #: the paper's 5x5 filter
MODEL_FORMAT = "rt2-ball-segmentation"
MODEL_VERSION = 1
COLOUR_ORDERS = ("RGB", "BGR")
#: per-channel input transforms T(p) of uint8 pixel values p (see the module docstring)
INPUT_TRANSFORMS = ("linear", "log")
#: colours of table-tennis balls a model may be trained for ("any": both, or not recorded)
BALL_COLOURS = ("any", "orange", "white")


def logit(p: float) -> float:
    """Probability in (0, 1) -> logit ``log(p / (1 - p))``."""
    return math.log(p / (1.0 - p))


def sigmoid(x):
    """Logit -> probability, for scalars or arrays (float64)."""
    return 1.0 / (1.0 + np.exp(-np.asarray(x, dtype=np.float64)))


def transform_lut(input_transform: str, log_offset_dn: float = 8.0) -> np.ndarray:
    """(256,) float32 table of ``T(p)`` for p = 0..255."""
    p = np.arange(256, dtype=np.float64)
    if input_transform == "linear":
        return p.astype(np.float32)
    if input_transform == "log":
        return np.log(p + log_offset_dn).astype(np.float32)
    raise ValueError(f"input_transform must be one of {INPUT_TRANSFORMS}, got {input_transform!r}")


@dataclass(frozen=True, eq=False)
class BallSegmentationModel:
    """A 5x5x3 linear filter + bias whose sigmoid is the per-pixel ball probability.

    kernel : (5, 5, 3) float32 weights, last axis in ``colour_order``, applied to scaled input
    bias : float, added to every pixel's logit
    colour_order : "RGB" or "BGR", channel order of ``kernel``, ``input_scale``, ``input_offset``
    input_scale, input_offset : (3,) per-channel scaling of the transformed input before the filter
    input_transform : "linear" (raw pixel values) or "log" (``log(p + log_offset_dn)``)
    log_offset_dn : offset inside the log, pixel values (damps the noise of dark pixels)
    t_high, t_low : recommended Algorithm 1 thresholds (probabilities, 0 < t_low < t_high < 1),
        chosen on the training run's validation split
    area_range_px : (2,) recommended accepted blob area [min, max], pixels (from the training labels)
    description : provenance (training command, data)
    ball_colour : the balls the model was trained to find: "orange", "white" or "any" (unknown, or
        both); evaluations score balls of this colour by default
    edge_loss_px : how much narrower than the ball its blob at ``t_low`` is, pixels (the rim stays under
        ``t_low``; nearly the same at every ball size): the pipeline's 3D size test adds it to every
        blob's width (``TrackerOptions.blob_edge_px``). Measured on rendered frame sets for the shipped
        model (2.8; ``rt2 eval framesets`` prints the fit, docs/pipeline.md step 8); 0 for files written before the field existed and for the hand-made model
    verifier : optional :class:`~tracker.detection.verifier.CandidateVerifier`, the classifier our
        detector runs on its candidates' crops (None: the filter alone decides, as in the paper)
    learned : optional :class:`~tracker.detection.learned.LearnedStage`, the heatmap network our detector
        (``method="ours"``) finds candidates with instead of the filter; the filter stays for the paper's
        method (``rt2-paper``). None: the filter and Algorithm 1 for both
    """

    kernel: np.ndarray
    bias: float
    colour_order: str = "RGB"
    input_scale: np.ndarray = field(default_factory=lambda: np.full(3, 1.0 / 255.0))
    input_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    input_transform: str = "linear"
    log_offset_dn: float = 8.0
    t_high: float = 0.5
    t_low: float = 0.25
    area_range_px: np.ndarray = field(default_factory=lambda: np.array([3.0, 3000.0]))
    description: str = ""
    ball_colour: str = "any"
    edge_loss_px: float = 0.0
    verifier: "CandidateVerifier | None" = None
    learned: "LearnedStage | None" = None
    # Derived at construction: the kernel for T(uint8 RGB channels) with the scaling folded in.
    _kernel_crgb: np.ndarray = field(init=False, repr=False, compare=False)
    _bias_eff: float = field(init=False, repr=False, compare=False)
    _kernel_coarse: np.ndarray = field(init=False, repr=False, compare=False)
    _lut: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        where = "BallSegmentationModel"
        kernel = np.asarray(self.kernel)
        if kernel.shape != (KERNEL_SIZE, KERNEL_SIZE, 3):
            raise ValueError(f"{where}: kernel must have shape (5, 5, 3), got shape {kernel.shape}")
        if kernel.dtype.kind not in "biuf":
            raise ValueError(f"{where}: kernel must be real numbers, got dtype {kernel.dtype}")
        kernel = kernel.astype(np.float32)
        scale = _real_vector(self.input_scale, "input_scale", where)
        offset = _real_vector(self.input_offset, "input_offset", where)
        for name, arr in (("input_scale", scale), ("input_offset", offset)):
            if arr.shape != (3,):
                raise ValueError(f"{where}: {name} must have 3 values (one per channel), got shape {arr.shape}")
        for name, arr in (("kernel", kernel), ("input_scale", scale), ("input_offset", offset)):
            if not np.isfinite(arr).all():
                raise ValueError(f"{where}: {name} must be finite")
        if (scale == 0).any():
            raise ValueError(f"{where}: input_scale must be non-zero for every channel (a zero scale ignores "
                             f"that colour), got {scale.tolist()}")
        if self.colour_order not in COLOUR_ORDERS:
            raise ValueError(f"{where}: colour_order must be one of {COLOUR_ORDERS}, got {self.colour_order!r}")
        bias = float(self.bias)
        if not math.isfinite(bias):
            raise ValueError(f"{where}: bias must be finite, got {self.bias!r}")
        t_high, t_low = float(self.t_high), float(self.t_low)
        if not (0.0 < t_low < t_high < 1.0):
            raise ValueError(f"{where}: thresholds must satisfy 0 < t_low < t_high < 1, got t_low={t_low}, t_high={t_high}")
        if self.ball_colour not in BALL_COLOURS:
            raise ValueError(f"{where}: ball_colour must be one of {BALL_COLOURS}, got {self.ball_colour!r}")
        if self.input_transform not in INPUT_TRANSFORMS:
            raise ValueError(f"{where}: input_transform must be one of {INPUT_TRANSFORMS}, got {self.input_transform!r}")
        log_offset = float(self.log_offset_dn)
        if not (math.isfinite(log_offset) and log_offset > 0):
            raise ValueError(f"{where}: log_offset_dn must be a positive number, got {self.log_offset_dn!r}")
        edge = self.edge_loss_px
        if isinstance(edge, bool) or not isinstance(edge, (int, float, np.floating, np.integer)) or not (math.isfinite(edge) and edge >= 0):
            raise ValueError(f"{where}: edge_loss_px must be a number of pixels >= 0, got {edge!r}")
        object.__setattr__(self, "edge_loss_px", float(edge))
        if self.verifier is not None and not isinstance(self.verifier, CandidateVerifier):
            raise ValueError(f"{where}: verifier must be a CandidateVerifier or None, got {describe(self.verifier)}")
        if self.learned is not None and not isinstance(self.learned, LearnedStage):
            raise ValueError(f"{where}: learned must be a LearnedStage or None, got {describe(self.learned)}")
        area = np.asarray(self.area_range_px, dtype=np.float64).reshape(-1)
        if area.shape != (2,) or not np.isfinite(area).all() or not 1 <= area[0] <= area[1]:
            raise ValueError(f"{where}: area_range_px must be [min, max] with 1 <= min <= max, got {self.area_range_px!r}")
        area.setflags(write=False)
        object.__setattr__(self, "area_range_px", area)
        object.__setattr__(self, "log_offset_dn", log_offset)
        for name, arr in (("kernel", kernel), ("input_scale", scale), ("input_offset", offset)):
            arr.setflags(write=False)
        object.__setattr__(self, "kernel", kernel)
        object.__setattr__(self, "input_scale", scale)
        object.__setattr__(self, "input_offset", offset)
        object.__setattr__(self, "bias", bias)
        object.__setattr__(self, "t_high", t_high)
        object.__setattr__(self, "t_low", t_low)
        # Fold the scaling: sum_c K_c * (s_c x_c + o_c) = sum_c (s_c K_c) * x_c + sum_c o_c sum(K_c).
        # Exact with reflected borders (a constant image stays constant under reflection).
        order = [0, 1, 2] if self.colour_order == "RGB" else [2, 1, 0]  # RGB channel -> kernel channel
        k64 = kernel.astype(np.float64)
        kernel_crgb = np.stack([(k64[:, :, order[c]] * scale[order[c]]).astype(np.float32) for c in range(3)])  # (3, 5, 5): RGB first
        bias_eff = bias + float(sum(offset[c] * k64[:, :, c].sum() for c in range(3)))
        object.__setattr__(self, "_kernel_crgb", kernel_crgb)
        object.__setattr__(self, "_bias_eff", bias_eff)
        object.__setattr__(self, "_kernel_coarse", coarse_kernel(kernel_crgb))
        object.__setattr__(self, "_lut", transform_lut(self.input_transform, log_offset))  # T of the 256 channel values

    # -- inference -----------------------------------------------------------------------------
    @property
    def kernel_rgb_uint8(self) -> np.ndarray:
        """(5, 5, 3) float32 effective kernel for ``T`` of the uint8 RGB channels (scaling folded in)."""
        return np.ascontiguousarray(np.moveaxis(self._kernel_crgb, 0, -1))

    @property
    def bias_uint8(self) -> float:
        """Effective bias for ``T`` of the uint8 RGB channels (scaling folded in)."""
        return self._bias_eff

    def transformed(self, image: np.ndarray) -> np.ndarray:
        """(H, W, 3) float32 ``T(image)`` (RGB), the input of the effective kernel."""
        check_image(image)
        lut = transform_lut(self.input_transform, self.log_offset_dn)
        return lut[image]

    def logits(self, image: np.ndarray, window=None) -> np.ndarray:
        """Per-pixel ball logit.

        image : (H, W, 3) uint8 RGB
        window : optional ``(x0, y0, x1, y1)`` pixel bounds (x1, y1 exclusive, inside the image):
            compute only this window; the values equal the full-frame ones there
        returns (h, w) float32 logits (the whole image, or the window)
        """
        check_image(image)
        if window is None:
            return self.logits_trusted(image)
        x0, y0, x1, y1 = (int(v) for v in window)
        h, w = image.shape[:2]
        if not (0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h):
            raise ValueError(f"window must satisfy 0 <= x0 < x1 <= {w} and 0 <= y0 < y1 <= {h}, got {tuple(window)}")
        return self.logits_window_trusted(image, x0, y0, x1, y1)

    def probability(self, image: np.ndarray, window=None) -> np.ndarray:
        """Per-pixel ball probability ``B`` (paper Algorithm 1 input): (h, w) float32 in [0, 1]."""
        return sigmoid(self.logits(image, window)).astype(np.float32)

    def logits_trusted(self, image: np.ndarray, work: "LogitWorkspace | None" = None) -> np.ndarray:
        """(H, W) float32 logits of a trusted image; into ``work``'s buffers when given (its ``out``,
        overwritten by the next call with it), else into new arrays. Same operations either way, so
        the same bytes: the buffers only spare the allocations (a VGA frame's logits: ~300 page faults)."""
        h, w = image.shape[:2]
        if work is None:
            t, out = np.empty(scratch_shape(h, w), np.float32), np.empty((h, w), np.float32)
        else:
            t, out = work.buffers((h, w))
        correlate_5x5x3(np.ascontiguousarray(image), self._lut, self._kernel_crgb, np.float32(self._bias_eff), 0, 0, w, h, t, out)
        return out

    def logits_window_trusted(self, image, x0, y0, x1, y1) -> np.ndarray:
        """(y1 - y0, x1 - x0) float32 logits of a trusted window of a trusted image (the pixels around
        the window are read too: the values are the full frame's there, bit for bit)."""
        h, w = y1 - y0, x1 - x0
        out = np.empty((h, w), np.float32)
        correlate_5x5x3(np.ascontiguousarray(image), self._lut, self._kernel_crgb, np.float32(self._bias_eff),
                        x0, y0, x1, y1, np.empty(scratch_shape(h, w), np.float32), out)
        return out

    def logits_coarse_trusted(self, image: np.ndarray, work: "LogitWorkspace") -> np.ndarray:
        """(ceil(H / 2), ceil(W / 2)) float32 approximate logits of every other pixel of every other row of a trusted
        image, from those pixels alone (:func:`tracker.detection._correlate.coarse_logits`), into ``work``'s buffer."""
        h, w = image.shape[:2]
        t, out = work.coarse_buffers((h, w))
        coarse_logits(np.ascontiguousarray(image), self._lut, self._kernel_coarse, np.float32(self._bias_eff), t, out)
        return out

    def logits_blocks_trusted(self, image: np.ndarray, blocks: np.ndarray, work: "LogitWorkspace") -> np.ndarray:
        """The (H, W) float32 logits of a trusted image inside the boxes ``blocks`` ((n, 4) int64 ``x0, y0, x1, y1``,
        each inside the image) and -inf elsewhere, into ``work``'s full-frame buffer (the previous call's boxes are
        reset, not the whole frame): the full frame's values in the boxes, bit for bit."""
        h, w = image.shape[:2]
        return self._into_blocks(image, blocks, work, work.sparse_buffer((h, w), blocks))

    def logits_more_blocks_trusted(self, image: np.ndarray, blocks: np.ndarray, work: "LogitWorkspace") -> np.ndarray:
        """:meth:`logits_blocks_trusted`'s buffer with the logits of the boxes ``blocks`` added (the others kept)."""
        return self._into_blocks(image, blocks, work, work.sparse_extend(blocks))

    def _into_blocks(self, image, blocks, work, out) -> np.ndarray:
        h = image.shape[0]
        widest = int((blocks[:, 2] - blocks[:, 0]).max()) if len(blocks) else 0
        t = work.scratch((h, max(widest, 1)))
        correlate_5x5x3_blocks(np.ascontiguousarray(image), self._lut, self._kernel_crgb, np.float32(self._bias_eff), blocks, t, out)
        return out

    # -- files ---------------------------------------------------------------------------------
    def save(self, path) -> Path:
        """Write the model to ``path`` (.npz, no pickle); returns the path."""
        path = Path(path)
        if path.suffix != ".npz":
            raise ValueError(f"model file must end in .npz, got {str(path)!r}")
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(
            path,
            format=np.array(MODEL_FORMAT),
            version=np.array(MODEL_VERSION),
            kernel=self.kernel,
            bias=np.array(self.bias),
            colour_order=np.array(self.colour_order),
            input_scale=self.input_scale,
            input_offset=self.input_offset,
            input_transform=np.array(self.input_transform),
            log_offset_dn=np.array(self.log_offset_dn),
            t_high=np.array(self.t_high),
            t_low=np.array(self.t_low),
            area_range_px=self.area_range_px,
            description=np.array(self.description),
            ball_colour=np.array(self.ball_colour),
            edge_loss_px=np.array(self.edge_loss_px),
            **({} if self.verifier is None else self.verifier.to_fields()),
            **({} if self.learned is None else self.learned.to_fields()),
        )
        return path

    @classmethod
    def load(cls, path) -> "BallSegmentationModel":
        """Read a model written by :meth:`save`; ``ValueError`` naming the file and field otherwise."""
        path = Path(path)
        src = str(path)
        if not path.is_file():
            raise FileNotFoundError(f"model file {src!r} does not exist")
        data = load_npz_checked(path, "model file")
        fmt = _scalar(data, "format", str, src)
        if fmt != MODEL_FORMAT:
            raise ValueError(f"{src}: field 'format' must be {MODEL_FORMAT!r}, got {fmt!r}")
        version = _scalar(data, "version", int, src)
        if version != MODEL_VERSION:
            raise ValueError(f"{src}: field 'version' is {version}, this rt2 reads version {MODEL_VERSION}")
        kernel = _field(data, "kernel", src)
        if kernel.shape != (KERNEL_SIZE, KERNEL_SIZE, 3):
            raise ValueError(f"{src}: field 'kernel' must have shape (5, 5, 3) (a 5x5 filter over 3 channels), got shape {kernel.shape}")
        try:
            return cls(
                kernel=kernel,
                bias=_scalar(data, "bias", float, src),
                colour_order=_scalar(data, "colour_order", str, src),
                input_scale=_field(data, "input_scale", src),
                input_offset=_field(data, "input_offset", src),
                input_transform=_scalar(data, "input_transform", str, src),
                log_offset_dn=_scalar(data, "log_offset_dn", float, src),
                t_high=_scalar(data, "t_high", float, src),
                t_low=_scalar(data, "t_low", float, src),
                area_range_px=_field(data, "area_range_px", src),
                description=_scalar(data, "description", str, src) if "description" in data else "",
                # optional: files written before the field existed say nothing of their balls' colour
                ball_colour=_scalar(data, "ball_colour", str, src) if "ball_colour" in data else "any",
                edge_loss_px=_scalar(data, "edge_loss_px", float, src) if "edge_loss_px" in data else 0.0,
                # optional: the candidate verifier (files without it: the filter alone decides)
                verifier=CandidateVerifier.from_fields(data, src),
                # optional: the learned stage (files without it: the filter and Algorithm 1 find the candidates)
                learned=LearnedStage.from_fields(data, src),
            )
        except ValueError as exc:
            raise ValueError(f"{src}: {exc}") from None


def _real_vector(value, name: str, where: str) -> np.ndarray:
    arr = np.asarray(value)
    if arr.dtype.kind not in "biuf":
        raise ValueError(f"{where}: {name} must be real numbers, got {describe(value)}")
    return arr.astype(np.float64).reshape(-1)


def _field(data: dict, key: str, src: str) -> np.ndarray:
    if key not in data:
        raise ValueError(f"{src}: missing field {key!r} (fields present: {sorted(data)})")
    arr = data[key]
    if arr.dtype.kind not in "biufU":
        raise ValueError(f"{src}: field {key!r} has unsupported dtype {arr.dtype} (real numbers or text expected)")
    return arr


def _scalar(data: dict, key: str, kind: type, src: str):
    arr = _field(data, key, src)
    if arr.shape != ():
        raise ValueError(f"{src}: field {key!r} must be a scalar, got shape {arr.shape}")
    if kind is str:
        if arr.dtype.kind != "U":
            raise ValueError(f"{src}: field {key!r} must be a string, got dtype {arr.dtype}")
        return str(arr)
    if not np.issubdtype(arr.dtype, np.number):
        raise ValueError(f"{src}: field {key!r} must be a number, got dtype {arr.dtype}")
    value = arr.item()
    if kind is int:
        if not float(value).is_integer():
            raise ValueError(f"{src}: field {key!r} must be an integer, got {value!r}")
        return int(value)
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{src}: field {key!r} must be finite, got {value!r}")
    return value


class LogitWorkspace:
    """Reusable buffers for :meth:`BallSegmentationModel.logits_trusted` on full frames of one size at a time.

    One per thread (the buffers are overwritten by every call); ``buffers(shape)`` returns the float32
    scratch of the transformed rows (:func:`tracker.detection._correlate.scratch_shape`) and the (H, W)
    float32 logits, reallocated only when the frame size changes.
    """

    def __init__(self):
        self._shape = None
        self._bufs = None
        self._coarse = (None, None)
        self._sparse = None
        self._scratch = np.empty((3, 5, 0), np.float32)
        self._filled = np.zeros((0, 4), np.int64)  # the boxes of the sparse buffer that hold logits (the rest: -inf)

    def buffers(self, shape) -> tuple:
        shape = tuple(int(v) for v in shape)
        if shape != self._shape:
            self._bufs = (np.empty(scratch_shape(*shape), np.float32), np.empty(shape, np.float32))
            self._shape = shape
        return self._bufs

    def coarse_buffers(self, shape) -> tuple:
        """The scratch and the (ceil(H / 2), ceil(W / 2)) output of the coarse logits of frames of ``shape``."""
        shape = tuple(int(v) for v in shape)
        if self._coarse[0] != shape:
            h, w = shape
            self._coarse = (shape, (np.empty(coarse_scratch_shape(h, w), np.float32), np.empty(((h + 1) // 2, (w + 1) // 2), np.float32)))
        return self._coarse[1]

    def sparse_buffer(self, shape, blocks: np.ndarray) -> np.ndarray:
        """An (H, W) float32 buffer of -inf, for logits to be written in the boxes ``blocks`` (remembered: the next call
        resets them, not the whole frame)."""
        shape = tuple(int(v) for v in shape)
        if self._sparse is None or self._sparse.shape != shape:
            self._sparse = np.full(shape, -np.inf, np.float32)
        else:
            for x0, y0, x1, y1 in self._filled:
                self._sparse[y0:y1, x0:x1] = -np.inf
        self._filled = blocks
        return self._sparse

    @property
    def filled_boxes(self) -> np.ndarray:
        """(n, 4) int64 the boxes of the sparse buffer that hold logits (the rest of it is -inf)."""
        return self._filled

    def sparse_extend(self, blocks: np.ndarray) -> np.ndarray:
        """The buffer of :meth:`sparse_buffer`, its boxes now also ``blocks`` (to be written by the caller)."""
        self._filled = np.concatenate([self._filled, blocks])
        return self._sparse

    def scratch(self, shape) -> np.ndarray:
        """A transformed-rows scratch wide enough for windows of ``shape`` (grown, never shrunk)."""
        need = scratch_shape(*shape)
        if self._scratch.shape[2] < need[2]:
            self._scratch = np.empty(need, np.float32)
        return self._scratch
