"""Camera sources: one :class:`~harness.live.frames.FrameSource` per rig camera, from one of several backends.

``open_sources(parse_source_spec(["sim"]), rig, rate_hz=200.0, seed=0)`` returns the sources in rig
order; :class:`harness.live.assembly.FrameSetAssembler` groups their frames into frame sets.

| spec | backend |
|---|---|
| ``sim`` | the simulated lab rendered in real time (:mod:`.sim`) |
| ``replay LOG.mcap`` | the images of a session log (:mod:`.replay`) |
| ``video DIR`` | per-camera video files or image folders with timestamps (:mod:`.video`) |
| ``opencv 0,1,2,3`` | USB / V4L2 cameras (or files, stream URLs) through cv2.VideoCapture (:mod:`.opencv`) |
| ``pylon [SERIALS]`` | Basler cameras through pypylon, extra ``rt2[cameras]`` (:mod:`.pylon`) |
| ``genicam [X.cti] [SERIALS]`` | GenICam / GenTL cameras through harvesters, extra ``rt2[cameras]`` (:mod:`.genicam`) |

Every source stamps ``t_host_s = time.monotonic()`` at arrival and ``t_device_s`` where the camera
gives one. docs/live.md, section "Camera sources".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from harness.live.sources.drivers import SourceUnavailable, require_driver

__all__ = ["KINDS", "SourceSpec", "SourceUnavailable", "open_sources", "parse_source_spec", "require_driver"]

KINDS = ("sim", "replay", "video", "opencv", "pylon", "genicam")
_USAGE = ("sim | replay LOG.mcap | video DIR | opencv IDS (e.g. 0,1,2,3) | pylon [SERIALS] | "
          "genicam [PRODUCER.cti] [SERIALS]")
@dataclass(frozen=True)
class SourceSpec:
    """kind : one of :data:`KINDS`; target : LOG / DIR / CTI path or None; devices : camera ids or serials
    in rig order (opencv: ints or paths/URLs; pylon, genicam: serial numbers or user ids), or ()."""

    kind: str
    target: str | None = None
    devices: tuple = ()

    def __str__(self) -> str:
        parts = [self.kind] + ([self.target] if self.target else []) + ([",".join(map(str, self.devices))]
                                                                      if self.devices else [])
        return " ".join(parts)


def _device_list(text: str, *, indices: bool = False) -> tuple:
    """Comma-separated ids; ``indices``: digits become device indices (opencv), else serials stay text."""
    items = [t.strip() for t in text.split(",")]
    if not text.strip() or any(not t for t in items):
        raise ValueError(f"camera list must be comma-separated ids, got {text!r}")
    return tuple(int(t) if indices and t.isdigit() else t for t in items)


def parse_source_spec(tokens) -> SourceSpec:
    """``["sim"]``, ``["replay", "LOG.mcap"]``, ``["video", "DIR"]``, ``["opencv", "0,1,2,3"]``,
    ``["pylon"]``, ``["pylon", "SER0,SER1,..."]``, ``["genicam"]``, ``["genicam", "X.cti", "SER0,..."]``
    (or the same as one string) -> :class:`SourceSpec`. Device lists may also be separate tokens
    (``["opencv", "0", "1"]``); a genicam producer is recognised by its ``.cti`` suffix. Bad specs
    raise ValueError quoting them."""
    if isinstance(tokens, SourceSpec):
        return tokens
    parts = tokens.split() if isinstance(tokens, str) else [str(t) for t in tokens]
    if not parts:
        raise ValueError(f"empty camera source; use {_USAGE}")
    kind, args = parts[0], parts[1:]
    if kind not in KINDS:
        raise ValueError(f"unknown camera source {kind!r}; use {_USAGE}")
    bad = ValueError(f"camera source {' '.join(parts)!r}: use {_USAGE}")
    if kind == "sim":
        if args:
            raise bad
        return SourceSpec("sim")
    if kind in ("replay", "video"):
        if len(args) != 1:
            raise bad
        return SourceSpec(kind, args[0])
    if kind == "opencv":
        if not args:
            raise bad
        return SourceSpec(kind, None, _device_list(",".join(args), indices=True))
    if kind == "pylon":
        return SourceSpec(kind, None, _device_list(",".join(args)) if args else ())
    cti = args[0] if args and args[0].lower().endswith(".cti") else None  # genicam
    rest = args[1:] if cti else args
    return SourceSpec(kind, cti, _device_list(",".join(rest)) if rest else ())


def open_sources(spec, rig, *, rate_hz: float = 200.0, seed: int = 0, speed: float | None = 1.0,
                 scene_provider=None, queue_len: int = 8, **backend_options) -> list:
    """Open one source per camera of ``rig`` (rig order) for ``spec`` (a :class:`SourceSpec` or tokens).

    rate_hz : frame rate (sim: scene rate; video without timestamps: playback rate; opencv, pylon:
        requested camera rate; pylon software trigger: trigger rate)
    seed : sim's scene and noise; speed : sim / replay / video pacing (1.0 real time, None as fast as
        possible); scene_provider : sim only, ``t_s -> harness.sim.render.Scene``
    backend_options : passed to the backend (e.g. sim: ``prerender_s``, ``duration_s``; pylon:
        ``trigger``, ``emulator_images``; genicam: ``cti``)

    The sources are not started (``FrameSetAssembler`` starts them). Raises ValueError for a bad spec
    or a camera count that does not match the rig, :class:`SourceUnavailable` for a missing driver or
    a device that does not open.
    """
    spec = parse_source_spec(spec)
    if not (isinstance(rate_hz, (int, float)) and math.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"rate_hz must be > 0, got {rate_hz!r}")
    n = len(rig.cameras)
    if spec.devices and len(spec.devices) != n:
        raise ValueError(f"camera source {str(spec)!r} lists {len(spec.devices)} camera(s) but the rig has {n} "
                         f"({', '.join(rig.names)}); give one per rig camera, in rig order")
    if spec.kind == "sim":
        from harness.live.sources.sim import SimOptions, open_sim

        options = SimOptions(rate_hz=float(rate_hz), seed=seed, speed=speed, queue_len=queue_len, **backend_options)
        sources, _ = open_sim(rig, options, scene_provider=scene_provider)
    elif spec.kind == "replay":
        from harness.live.sources.replay import open_replay

        sources, _ = open_replay(spec.target, rig, speed=speed, queue_len=queue_len, **backend_options)
    elif spec.kind == "video":
        from harness.live.sources.video import open_video

        sources, _ = open_video(spec.target, rig, rate_hz=rate_hz, speed=speed, queue_len=queue_len, **backend_options)
    elif spec.kind == "opencv":
        from harness.live.sources.opencv import open_opencv

        sources = open_opencv(spec.devices, rig, rate_hz=rate_hz, **backend_options)
    elif spec.kind == "pylon":
        from harness.live.sources.pylon import open_pylon

        sources = open_pylon(rig, serials=spec.devices or None, rate_hz=rate_hz, **backend_options)
    else:
        from harness.live.sources.genicam import open_genicam

        sources = open_genicam(rig, cti=spec.target, serials=spec.devices or None, rate_hz=rate_hz, **backend_options)
    if len(sources) != n:  # a backend bug, never silently fewer cameras
        raise ValueError(f"{spec.kind}: opened {len(sources)} camera(s) for a rig of {n}")
    return sources
