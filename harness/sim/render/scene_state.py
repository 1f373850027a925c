"""The dynamic scene state the renderer draws over the static lab: immutable, world frame, metres.

A :class:`Scene` holds balls, capsules (robot links, human limbs, racket handles), spheres and boxes
(distractor objects), disks (racket blades) and the camera exposure of one instant. Positions are
at the *middle* of the exposure; a ball moving with ``velocity_mps`` is smeared over
``exposure.exposure_s`` around it. Colours are linear RGB reflectances in [0, 1] or a name from
:data:`COLOURS`. Every field is validated once, here, and the arrays are made read-only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["COLOURS", "Ball", "Box", "Capsule", "Disk", "Exposure", "Scene", "Sphere", "colour_rgb"]

#: Named reflectances (linear RGB). Skin tones span light to dark; "orange"/"white" are ball colours.
COLOURS: dict[str, tuple[float, float, float]] = {
    "orange": (1.0, 0.42, 0.06),
    "white": (0.92, 0.92, 0.9),
    "skin_light": (0.86, 0.62, 0.5),
    "skin_medium": (0.72, 0.47, 0.33),
    "skin_tan": (0.6, 0.4, 0.26),
    "skin_dark": (0.36, 0.23, 0.16),
    "robot_grey": (0.55, 0.56, 0.58),
    "robot_black": (0.07, 0.07, 0.08),
    "racket_red": (0.75, 0.08, 0.07),
    "racket_black": (0.05, 0.05, 0.05),
    "wood": (0.62, 0.45, 0.26),
    "shirt_blue": (0.12, 0.22, 0.55),
    "shirt_red": (0.7, 0.1, 0.12),
    "shirt_black": (0.06, 0.06, 0.07),
    "shirt_green": (0.12, 0.45, 0.2),
    "jeans": (0.15, 0.2, 0.35),
    "hair_dark": (0.08, 0.06, 0.05),
    "hair_brown": (0.3, 0.18, 0.1),
    "yellow": (0.9, 0.75, 0.1),
}


def colour_rgb(value, name: str = "colour") -> np.ndarray:
    """A colour name from :data:`COLOURS` or three numbers in [0, 1] -> (3,) float array (read-only)."""
    if isinstance(value, str):
        if value not in COLOURS:
            raise ValueError(f"unknown {name} {value!r}; valid names: {sorted(COLOURS)} or an (r, g, b) triple in [0, 1]")
        rgb = np.array(COLOURS[value], float)
    else:
        try:
            rgb = np.array(value, float)
        except (TypeError, ValueError):
            raise ValueError(f"{name} must be a colour name or (r, g, b) in [0, 1], got {value!r}") from None
        if rgb.shape != (3,) or not np.isfinite(rgb).all() or (rgb < 0).any() or (rgb > 1).any():
            raise ValueError(f"{name} must be a colour name or (r, g, b) in [0, 1], got {value!r}")
    rgb.setflags(write=False)
    return rgb


def _vec(obj, name: str, value, shape=(3,)) -> np.ndarray:
    try:
        arr = np.array(value, float)
    except (TypeError, ValueError):
        raise ValueError(f"{type(obj).__name__}.{name} must be numeric with shape {shape}, got {value!r}") from None
    if arr.shape != shape:
        raise ValueError(f"{type(obj).__name__}.{name} must have shape {shape}, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{type(obj).__name__}.{name} must be finite, got {arr.tolist()}")
    arr.setflags(write=False)
    object.__setattr__(obj, name, arr)
    return arr


def _positive(obj, name: str, lo: float = 0.0, hi: float = np.inf) -> float:
    v = getattr(obj, name)
    if isinstance(v, bool) or not isinstance(v, (int, float, np.number)) or not (lo < float(v) <= hi):
        raise ValueError(f"{type(obj).__name__}.{name} must be a number in ({lo:g}, {hi:g}], got {v!r}")
    object.__setattr__(obj, name, float(v))
    return float(v)


def _fraction(obj, name: str) -> None:
    v = getattr(obj, name)
    if isinstance(v, bool) or not isinstance(v, (int, float, np.number)) or not (0.0 <= float(v) <= 1.0):
        raise ValueError(f"{type(obj).__name__}.{name} must be a number in [0, 1], got {v!r}")
    object.__setattr__(obj, name, float(v))


@dataclass(frozen=True)
class Ball:
    """A table-tennis ball: the object the data sets label.

    position_m : (3,) centre at mid-exposure, world frame
    velocity_mps : (3,) velocity, world frame (smears the ball over the exposure)
    colour : ``"orange"``, ``"white"`` or (r, g, b)
    radius_m : 0.02 for a 40 mm ball
    specular : strength of the glossy highlight (0 = matte)
    """

    position_m: np.ndarray
    velocity_mps: np.ndarray = (0.0, 0.0, 0.0)
    colour: object = "orange"
    radius_m: float = 0.02
    specular: float = 0.35

    def __post_init__(self):
        _vec(self, "position_m", self.position_m)
        _vec(self, "velocity_mps", self.velocity_mps)
        object.__setattr__(self, "colour", colour_rgb(self.colour, "Ball.colour"))
        _positive(self, "radius_m", 0.0, 0.5)
        _fraction(self, "specular")


@dataclass(frozen=True)
class Capsule:
    """A cylinder with hemispherical caps between ``p0_m`` and ``p1_m`` (a robot link, a forearm).

    p0_m, p1_m : (3,) axis end points, world frame; equal points make a sphere
    radius_m : cap and cylinder radius
    colour : name or (r, g, b); specular : highlight strength in [0, 1]
    """

    p0_m: np.ndarray
    p1_m: np.ndarray
    radius_m: float
    colour: object = "robot_grey"
    specular: float = 0.1

    def __post_init__(self):
        _vec(self, "p0_m", self.p0_m)
        _vec(self, "p1_m", self.p1_m)
        _positive(self, "radius_m", 0.0, 2.0)
        object.__setattr__(self, "colour", colour_rgb(self.colour, "Capsule.colour"))
        _fraction(self, "specular")


@dataclass(frozen=True)
class Sphere:
    """A sphere that is *not* a ball to label (an orange juggling ball, a lamp globe, a head).

    centre_m : (3,) world frame; radius_m; colour; specular
    """

    centre_m: np.ndarray
    radius_m: float
    colour: object = "orange"
    specular: float = 0.2

    def __post_init__(self):
        _vec(self, "centre_m", self.centre_m)
        _positive(self, "radius_m", 0.0, 2.0)
        object.__setattr__(self, "colour", colour_rgb(self.colour, "Sphere.colour"))
        _fraction(self, "specular")


@dataclass(frozen=True)
class Disk:
    """A flat round disk, two-sided (a racket blade: red on one side, black on the other).

    centre_m : (3,) world frame; normal : (3,) direction of the front side (normalised here)
    radius_m; colour_front, colour_back : names or (r, g, b); specular
    """

    centre_m: np.ndarray
    normal: np.ndarray
    radius_m: float = 0.075
    colour_front: object = "racket_red"
    colour_back: object = "racket_black"
    specular: float = 0.15

    def __post_init__(self):
        _vec(self, "centre_m", self.centre_m)
        n = _vec(self, "normal", self.normal)
        norm = float(np.linalg.norm(n))
        if norm < 1e-9:
            raise ValueError(f"Disk.normal must be a non-zero vector, got {n.tolist()}")
        unit = n / norm
        unit.setflags(write=False)
        object.__setattr__(self, "normal", unit)
        _positive(self, "radius_m", 0.0, 2.0)
        object.__setattr__(self, "colour_front", colour_rgb(self.colour_front, "Disk.colour_front"))
        object.__setattr__(self, "colour_back", colour_rgb(self.colour_back, "Disk.colour_back"))
        _fraction(self, "specular")


@dataclass(frozen=True)
class Box:
    """An oriented box (a cup, a sheet of paper, a bag).

    centre_m : (3,) world frame; size_m : (3,) edge lengths along the box axes
    R_box_to_world : (3, 3) rotation box -> world (identity: axis-aligned)
    colour; specular
    """

    centre_m: np.ndarray
    size_m: np.ndarray
    R_box_to_world: np.ndarray = field(default_factory=lambda: np.eye(3))
    colour: object = "white"
    specular: float = 0.05

    def __post_init__(self):
        _vec(self, "centre_m", self.centre_m)
        size = _vec(self, "size_m", self.size_m)
        if (size <= 0).any():
            raise ValueError(f"Box.size_m must be positive, got {size.tolist()}")
        R = _vec(self, "R_box_to_world", self.R_box_to_world, (3, 3))
        if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
            raise ValueError(f"Box.R_box_to_world must be a rotation matrix, got {R.tolist()}")
        object.__setattr__(self, "colour", colour_rgb(self.colour, "Box.colour"))
        _fraction(self, "specular")


@dataclass(frozen=True)
class Exposure:
    """Camera exposure and scene illumination of one frame.

    exposure_s : shutter time, seconds (motion blur length; brightness scales with it)
    gain : sensor gain (brightness and noise scale with it)
    light_level : scene illumination relative to the lab's nominal lighting (dimmed lights < 1)
    Image brightness is ``light_level * gain * exposure_s / RenderOptions.reference_exposure_s``.
    """

    exposure_s: float = 0.002
    gain: float = 1.0
    light_level: float = 1.0

    def __post_init__(self):
        _positive(self, "exposure_s", 0.0, 0.1)
        _positive(self, "gain", 0.0, 64.0)
        _positive(self, "light_level", 0.0, 10.0)


_GROUPS = {"balls": Ball, "capsules": Capsule, "spheres": Sphere, "disks": Disk, "boxes": Box}


@dataclass(frozen=True)
class Scene:
    """Everything dynamic in one frame set.

    balls, capsules, spheres, disks, boxes : tuples of the primitives above
    exposure : :class:`Exposure` shared by all cameras
    frame_index : integer that, with the renderer's seed, selects this frame's sensor noise, so a
        frame renders identically whatever order or process renders it
    """

    balls: tuple = ()
    capsules: tuple = ()
    spheres: tuple = ()
    disks: tuple = ()
    boxes: tuple = ()
    exposure: Exposure = Exposure()
    frame_index: int = 0

    def __post_init__(self):
        for name, kind in _GROUPS.items():
            items = getattr(self, name)
            if isinstance(items, (str, bytes)) or not hasattr(items, "__iter__"):
                raise ValueError(f"Scene.{name} must be a sequence of {kind.__name__}, got {items!r}")
            items = tuple(items)
            for i, item in enumerate(items):
                if not isinstance(item, kind):
                    raise ValueError(f"Scene.{name}[{i}] must be a {kind.__name__}, got {type(item).__name__}")
            object.__setattr__(self, name, items)
        if not isinstance(self.exposure, Exposure):
            raise ValueError(f"Scene.exposure must be an Exposure, got {type(self.exposure).__name__}")
        fi = self.frame_index
        if isinstance(fi, bool) or not isinstance(fi, (int, np.integer)) or fi < 0:
            raise ValueError(f"Scene.frame_index must be a non-negative integer, got {fi!r}")
        object.__setattr__(self, "frame_index", int(fi))
