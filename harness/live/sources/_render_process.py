"""The ``sim`` source's renderer in a child process, so that rendering runs on another core and never
holds the tracker's interpreter lock.

The child is a fresh interpreter (``python -m harness.live.sources._render_process``: nothing of the
parent's threads, locks or ``__main__`` is inherited, so it works from any script). It builds its
own :class:`harness.sim.render.Renderer` for the rig, then renders the frame sets it is asked for into a
ring of ``slots`` frame sets in shared memory and answers with the slot; the parent copies the
images out and gives the slot back.

The child runs at a lower CPU priority (``nice``, default +10): a simulated camera stands in for
hardware that renders on its own silicon, so on a busy machine the tracker's process gets the cores
first and the renderer takes what is left; a frame set it cannot render in time is skipped by the
``sim`` source and counted (``skipped``), as a camera drops the frames its host does not take. Requests are served in order; messages are pickles over the
child's stdin / stdout. The scene provider is pickled into the child, so it must be picklable
(:class:`~.sim.LauncherFlights` is; a lambda is not).
"""

from __future__ import annotations

import dataclasses
import os
import pickle
import queue
import subprocess
import sys
import threading
import time
from multiprocessing import shared_memory

import numpy as np

__all__ = ["RenderProcess"]


def _views(buf, shapes, slots: int) -> list[list[np.ndarray]]:
    per_set = sum(int(np.prod(s)) for s in shapes)
    out = []
    for slot in range(slots):
        offset, row = slot * per_set, []
        for s in shapes:
            n = int(np.prod(s))
            row.append(np.ndarray(s, np.uint8, buffer=buf, offset=offset))
            offset += n
        out.append(row)
    return out


def _serve(inp, out) -> None:
    """The child: read the set-up (the rig and its options, then the scene provider: the lab is ray-cast while the
    parent makes the scene), then requests ``(k, slot, t_s, drop_after_s)`` until None or end of input.

    ``drop_after_s``: host monotonic time after which starting frame set k is pointless (it could not be
    delivered in time), NaN = always render. Such a request is answered ``("skipped", k, slot)`` without
    rendering, so a renderer that fell behind spends its time on frame sets it can still deliver."""
    shm, views = None, None

    def send(msg) -> None:
        pickle.dump(msg, out)
        out.flush()

    try:
        rig_dict, render_options, seed, shm_name, shapes, slots, nice = pickle.load(inp)
        from harness.sim.render import Renderer, Scene
        from tracker import Rig

        shm = shared_memory.SharedMemory(name=shm_name)
        try:  # the parent owns the block: keep this process's resource tracker from unlinking it at exit
            from multiprocessing import resource_tracker

            resource_tracker.unregister(shm._name, "shared_memory")
        except Exception:  # noqa: BLE001 - Python versions differ; at worst a warning at exit
            pass
        renderer = Renderer(Rig.from_dict(rig_dict), render_options, seed=seed)  # while the parent makes the scene
        views = _views(shm.buf, shapes, slots)
        provider = pickle.load(inp)
        warm = provider(0.0)  # the first render compiles and allocates: paid before "ready", not by frame set 0
        if isinstance(warm, Scene):
            renderer.render(dataclasses.replace(warm, frame_index=0))  # noise is a function of (seed, frame index)
        if nice:  # after the start-up (ray-casting the lab), which the service waits for: then yield to the tracker
            os.nice(nice)
        send(("ready",))
        while True:
            try:
                req = pickle.load(inp)
            except EOFError:  # the parent is gone
                break
            if req is None:
                break
            k, slot, t_s, drop_after_s = req
            if time.monotonic() > drop_after_s:  # False for NaN
                send(("skipped", k, slot))
                continue
            scene = provider(t_s)
            if not isinstance(scene, Scene):
                raise ValueError(f"scene_provider({t_s:.4f}) returned {type(scene).__name__}, not a Scene")
            renderer.render(dataclasses.replace(scene, frame_index=k), out=views[slot])  # straight into the slot
            send(("done", k, slot))
    except BaseException as exc:  # noqa: BLE001 - reported to the parent, which raises it to the readers
        try:
            send(("error", f"{type(exc).__name__}: {exc}"))
        except (OSError, ValueError):
            pass
    finally:
        if shm is not None:
            views = None
            shm.close()


def _pickled(provider) -> bytes:
    """The scene provider as the child reads it; a clear error where it cannot be pickled."""
    try:
        return pickle.dumps(provider)
    except Exception as exc:  # noqa: BLE001 - any pickling failure means the same thing here
        raise ValueError(f"the sim renderer process needs a picklable scene_provider (a module-level function "
                         f"or an object such as LauncherFlights), got {provider!r}: {exc}") from None


class RenderProcess:
    """A child process rendering frame sets of ``rig`` (see the module docstring)."""

    def __init__(self, rig, render_options, seed: int, provider=None, *, slots: int = 16, start_timeout_s: float = 300.0,
                 nice: int = 10):
        """Starts the child and sends it the rig; with ``provider`` also :meth:`start` s it. Without, the child
        ray-casts the lab while the caller makes the scene provider, then calls :meth:`start`."""
        if isinstance(nice, bool) or not isinstance(nice, int) or not 0 <= nice <= 19:
            raise ValueError(f"the sim renderer's nice must be a whole number in [0, 19], got {nice!r}")
        scene = None if provider is None else _pickled(provider)  # refused before any child is started
        self.proc = None
        self.shapes = [(c.image_size[1], c.image_size[0], 3) for c in rig.cameras]
        self.slots = int(slots)
        per_set = sum(int(np.prod(s)) for s in self.shapes)
        self.shm = shared_memory.SharedMemory(create=True, size=per_set * self.slots)
        self.views = _views(self.shm.buf, self.shapes, self.slots)
        self._results: queue.Queue = queue.Queue()
        self.proc = subprocess.Popen([sys.executable, "-m", "harness.live.sources._render_process"],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        self._lock = threading.Lock()
        self._reader = threading.Thread(target=self._read_results, name="sim renderer results", daemon=True)
        self._reader.start()
        try:
            self._send((rig.to_dict(), render_options, seed, self.shm.name, self.shapes, self.slots, nice))
        except (BrokenPipeError, OSError):
            pass  # the child is gone already: start() reports what it said
        except BaseException:
            self.close()
            raise
        if scene is not None:
            self._start(scene, start_timeout_s)

    def start(self, provider, start_timeout_s: float = 300.0) -> None:
        """Send the scene provider and wait until the child has rendered its first frame set ("ready")."""
        try:
            scene = _pickled(provider)
        except BaseException:
            self.close()
            raise
        self._start(scene, start_timeout_s)

    def _start(self, scene: bytes, start_timeout_s: float) -> None:
        try:
            try:
                with self._lock:
                    self.proc.stdin.write(scene)
                    self.proc.stdin.flush()
            except (BrokenPipeError, OSError):
                pass  # the child is gone: its last words (or its exit) are read below
            deadline = time.monotonic() + start_timeout_s
            msg = None
            while msg is None and time.monotonic() < deadline:
                try:
                    msg = self._results.get(timeout=0.2)
                except queue.Empty:
                    if self.proc.poll() is not None and self._results.empty():
                        msg = ("error", f"it exited during start-up (exit code {self.proc.returncode})")
            if msg is None:
                raise ValueError(f"the sim renderer process did not start within {start_timeout_s:.0f} s")
            if msg[0] == "exit":
                msg = ("error", f"it exited during start-up (exit code {self.proc.wait(timeout=5.0)})")
            if msg[0] != "ready":
                raise ValueError(f"the sim renderer process failed to start: {msg[1]}")
        except BaseException:
            self.close()
            raise

    def _send(self, msg) -> None:
        with self._lock:
            pickle.dump(msg, self.proc.stdin)
            self.proc.stdin.flush()

    def _read_results(self) -> None:
        try:
            while True:
                self._results.put(pickle.load(self.proc.stdout))
        except (EOFError, OSError, ValueError, pickle.UnpicklingError):
            self._results.put(("exit",))

    def request(self, k: int, slot: int, t_s: float, drop_after_s: float = float("nan")) -> None:
        """Render frame set k (scene time ``t_s``) into ``slot``, unless the child starts it after host
        time ``drop_after_s`` (then :meth:`result` reports it skipped)."""
        try:
            self._send((int(k), int(slot), float(t_s), float(drop_after_s)))
        except (BrokenPipeError, OSError, ValueError):
            raise RuntimeError(f"the sim renderer process is gone (exit code {self.proc.poll()})") from None

    def result(self, timeout_s: float) -> tuple[int, int, bool] | None:
        """(k, slot, rendered) of the next answered request (``rendered`` False: skipped, too late to start),
        None on a timeout; raises what the child raised."""
        try:
            msg = self._results.get(timeout=timeout_s)
        except queue.Empty:
            return None
        if msg[0] == "error":
            raise RuntimeError(f"the sim renderer process failed: {msg[1]}")
        if msg[0] == "exit":
            raise RuntimeError(f"the sim renderer process died (exit code {self.proc.wait(timeout=5.0)})")
        return msg[1], msg[2], msg[0] == "done"

    def images(self, slot: int) -> tuple:
        """Copies of the frame set in ``slot`` (the slot may be reused at once)."""
        return tuple(v.copy() for v in self.views[slot])

    def close(self) -> None:
        if self.proc is not None:
            try:
                self._send(None)
                self.proc.stdin.close()
            except (BrokenPipeError, OSError, ValueError):
                pass
            try:
                self.proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=2.0)
            self._reader.join(timeout=2.0)
            self.proc.stdout.close()
            self.proc = None
        if self.shm is not None:
            self.views = None
            self.shm.close()
            self.shm.unlink()
            self.shm = None


if __name__ == "__main__":
    _pipe_out = sys.stdout.buffer
    sys.stdout = sys.stderr  # anything printed goes to stderr, never into the pickle stream
    _serve(sys.stdin.buffer, _pipe_out)
