"""Rendered frame sets of the simulated lab for the live-service tests (no camera code needed).

``rendered_images(n)`` renders a ball flying along the table through the lab rig once per process;
``assembled(...)`` turns them into :class:`AssembledFrameSet` objects stamped like live ones;
``drain(asm, n_max, timeout_s)`` takes frame sets from a running assembler.
"""

from __future__ import annotations

import functools
import time

import numpy as np

from harness.live.frames import AssembledFrameSet
from tracker import FrameSet

RIG = "lab4_vga"  # data/rigs/lab4_vga.yaml, whatever the working directory


@functools.lru_cache(maxsize=1)
def lab_rig():
    from tracker.rig_files import resolve_rig

    return resolve_rig(RIG)


@functools.lru_cache(maxsize=2)
def rendered_images(n: int = 24) -> tuple:
    """n frame sets (tuples of (480, 640, 3) uint8 per camera) of a ball moving at 5 m/s along x."""
    from harness.sim.render import Ball, Renderer, Scene

    r = Renderer(lab_rig(), seed=0)
    out = []
    for k in range(n):
        x = -1.6 + 0.025 * k
        scene = Scene(balls=(Ball(np.array([x, 0.1, 1.1]), np.array([5.0, 0.0, 0.0])),), frame_index=k)
        out.append(tuple(r.render(scene)))
    return tuple(out)


def assembled(n_sets: int, *, rate_hz: float = 200.0, drop_camera: int | None = None, drop_from: int = 0,
              pace: bool = False, due_stamps: bool = False):
    """Yield ``n_sets`` AssembledFrameSet cycling the rendered images; camera ``drop_camera`` has no frame
    from set ``drop_from`` on (None image and a note, as the assembler reports a stopped camera).
    pace : wait for each set's due time (a live camera's rate) instead of yielding at once.
    due_stamps : (with ``pace``) stamp each set at its due time, not at the moment it is yielded: the ball's times
        are a camera's at ``rate_hz`` however late a loaded machine yields them (with host stamps a consumer that
        lags spreads them out, and the ball of 5 m/s seems to crawl: the tracker's hypotheses then take it for no
        ball in play and search full frames)."""
    if due_stamps and not pace:
        raise ValueError("due_stamps needs pace (a set stamped before it is due would arrive from the future)")
    images = rendered_images()
    n_cams = len(images[0])
    t0 = time.monotonic()
    for k in range(n_sets):
        due = t0 + k / rate_hz
        if pace:
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        imgs = list(images[k % len(images)])
        notes = ()
        t_host = np.full(n_cams, due if due_stamps else time.monotonic())
        if drop_camera is not None and k >= drop_from:
            imgs[drop_camera] = None
            t_host[drop_camera] = np.nan
            notes = (f"camera {drop_camera}: no frame in time",)
        yield AssembledFrameSet(frameset=FrameSet(float(np.nanmin(t_host)), tuple(imgs), k), frame_id=k, t_host_s=t_host,
                                t_device_s=np.full(n_cams, np.nan), t_assembled_s=time.monotonic(), notes=notes)


def drain(asm, n_max: int, timeout_s: float = 3.0) -> list:
    """Up to ``n_max`` frame sets from the assembler ``asm`` (``get``/``finished``), until it has
    finished or ``timeout_s`` seconds have passed."""
    out = []
    deadline = time.monotonic() + timeout_s
    while len(out) < n_max and time.monotonic() < deadline:
        fs = asm.get(0.2)
        if fs is None and asm.finished:
            break
        if fs is not None:
            out.append(fs)
    return out
