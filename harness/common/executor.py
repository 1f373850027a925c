"""One executor for the studies' embarrassingly parallel sweeps: local worker processes or a Ray cluster.

    with Executor(SweepOptions(workers=2)) as ex:          # or SweepOptions(ray_address="auto")
        try:
            for index, result in ex.map(fn, tasks, initializer=init, initargs=(...,)):
                ...                                        # results as they finish, tagged with the task index
        except SweepStopped as stop:                       # a signal or a lost worker: keep what finished
            ...                                            # write the finished part, marked partial

Backends: ``workers == 1`` and no Ray runs the tasks in this process (today's behaviour); ``workers > 1``
uses a ``concurrent.futures.ProcessPoolExecutor`` of fresh (spawned) interpreters; ``ray_address`` hands
the tasks to Ray (``"local"``: a Ray instance on this machine; ``"auto"`` or ``host:port``: a running
cluster), which schedules them. We schedule nothing ourselves. ``fn`` and the tasks must be picklable
(module-level functions); ``initializer(*initargs)`` runs once per worker process before its first task
of that ``map`` call (e.g. to build a renderer), in every backend.

Same results whatever the backend and the number of workers: a task's result may depend only on the task
(its seed comes from the run seed and the task index, :mod:`harness.common.seeding`), never on which worker or in
which order it ran; callers put results back in task order (:func:`in_task_order`). Every task runs with one
BLAS thread, whatever the backend (a threaded BLAS may sum in another order with another thread count).

Crashes and signals: local workers die with the parent (``PR_SET_PDEATHSIG`` on Linux, plus a thread
watching the parent's pid everywhere), ignore SIGINT (the parent decides) and are killed at once when the
sweep stops. While the executor is open, SIGINT and SIGTERM raise :class:`SweepInterrupted` in the main
thread; the sweep kills its workers (work inside them is lost, finished results are kept) and the caller
writes what finished, marked partial. A worker that dies raises :class:`WorkerLost`.

An exception raised by a signal handler inside compiled code comes out wrapped: numba's dispatcher raises
``SystemError`` from it (`rt2 play` stopped by SIGTERM while its launcher's compiled flight ran ended in that
traceback); ``map`` takes an exception that was raised from the stop, once a signal came, as the stop.
An exception raised by a signal handler can be lost: Python prints and drops it when the handler runs inside
a ``__del__`` method or a weakref callback (numba and llvmlite free compiler objects that way while the main
process loads a kernel), and a library's ``except BaseException`` can swallow it. The stop therefore does not
rest on that one exception: until the sweep has acted on the stop (:meth:`Executor.close`, or ``map``
catching it), every poll of ``map`` (4 a second while it waits for workers, and each time the caller asks
for the next result) raises it again, and while a task runs in this process a watchdog thread re-delivers
the signal to the main thread every ``_REDELIVER_S``. Consume ``map`` in a ``for`` loop, so that an
exception leaving the loop closes the generator (and with it the workers).
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
import uuid
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from multiprocessing import get_context

from harness.common.fast_exit import exit_at_once_when_done
from harness.common.spawn import die_with_parent

__all__ = ["Executor", "SweepInterrupted", "SweepOptions", "SweepStopped", "WorkerLost", "add_sweep_arguments",
           "in_task_order", "options_from_args", "run_sweep"]

RAY_EXTRA_HINT = "pip install 'rt2[cluster]'"
_POLL_S = 0.25  #: how often the parent checks for finished tasks and workers check for their parent
_REDELIVER_S = 0.3  #: after a signal, how often it is sent again to the main thread until the sweep stops


class SweepStopped(BaseException):
    """Base of the ways a sweep stops early; ``done``/``total`` tasks had finished/were planned. A
    BaseException, so that no ``except Exception`` on the way swallows a stop."""

    exit_code = 1

    def __init__(self, message: str, *, done: int = 0, total: int = 0):
        super().__init__(message)
        self.done, self.total = done, total


def _caused_by(exc: BaseException, kind: type) -> bool:
    """Whether ``exc`` or an exception it was raised from (``__cause__``, ``__context__``) is a ``kind``: numba's
    compiled functions turn an exception raised inside them by a signal handler (their calls back into Python,
    e.g. to unpickle a constant) into ``SystemError: ... returned a result with an exception set``, from it."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, kind):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


class SweepInterrupted(SweepStopped, KeyboardInterrupt):
    """SIGINT or SIGTERM reached the main process during a sweep; ``exit_code`` = 128 + signal number."""

    def __init__(self, signum: int, *, done: int = 0, total: int = 0):
        self.signum = int(signum)
        self.exit_code = 128 + self.signum
        super().__init__(f"interrupted by {signal.Signals(self.signum).name}", done=done, total=total)


class WorkerLost(SweepStopped, RuntimeError):
    """A worker process (or Ray task) died or failed outside the task's own code."""


@dataclass(frozen=True)
class SweepOptions:
    """Where a sweep runs. workers : local processes (1 = this process); ray_address : None (local
    processes), ``"local"`` (start Ray on this machine), ``"auto"`` or ``host:port`` (a running cluster)."""

    workers: int = 1
    ray_address: str | None = None

    def __post_init__(self):
        if isinstance(self.workers, bool) or not isinstance(self.workers, int) or self.workers < 1:
            raise ValueError(f"--workers must be >= 1 (an integer), got {self.workers!r}")
        if self.ray_address is not None and (not isinstance(self.ray_address, str) or not self.ray_address.strip()):
            raise ValueError(f"--ray: address must be 'local', 'auto' or host:port, got {self.ray_address!r}")

    @property
    def backend(self) -> str:
        return "ray" if self.ray_address is not None else ("processes" if self.workers > 1 else "this process")


def add_sweep_arguments(parser, *, workers_default: int = 1) -> None:
    """``--workers W`` and ``--ray [ADDRESS]`` on a study's parser."""
    parser.add_argument("--workers", type=int, default=workers_default, metavar="W",
                        help=f"local worker processes (default {workers_default}); results do not depend on it")
    parser.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS",
                        help="run the tasks on Ray instead: no ADDRESS = a Ray instance on this machine, 'auto' or "
                             f"host:port = a running cluster (needs {RAY_EXTRA_HINT}); same results as local")


def options_from_args(args) -> SweepOptions:
    """The :class:`SweepOptions` of ``--workers`` / ``--ray``; without Ray installed ``--ray`` is a ValueError."""
    opts = SweepOptions(workers=args.workers, ray_address=getattr(args, "ray", None))
    if opts.ray_address is not None:
        _import_ray()
    return opts


def in_task_order(results, start: int = 0):
    """Re-order ``(index, result)`` pairs from :meth:`Executor.map` into task order (yields the same pairs)."""
    buffered, next_i = {}, start
    for index, result in results:
        buffered[index] = result
        while next_i in buffered:
            yield next_i, buffered.pop(next_i)
            next_i += 1


def run_sweep(options: SweepOptions, fn, tasks, *, stopped: list | None = None, on_result=None, **map_kw) -> dict:
    """{task index: result} of every task, on a fresh :class:`Executor`; ``on_result(index)`` after each.

    stopped : if a list is given, a sweep stopped early (:class:`SweepStopped`) is appended to it and the
    results of the tasks that finished are returned; else the stop propagates. map_kw : see :meth:`Executor.map`."""
    results = {}
    try:
        with Executor(options) as ex:
            for i, r in ex.map(fn, tasks, **map_kw):
                results[i] = r
                if on_result is not None:
                    on_result(i)
    except SweepStopped as stop:
        if stopped is None:
            raise
        stopped.append(stop)
    return results


def _import_ray():
    try:
        import ray
    except ImportError:
        raise ValueError(f"--ray needs Ray, which is not installed: {RAY_EXTRA_HINT}") from None
    return ray


# ------------------------------------------------------------------------------------------ worker side
_STATE: dict = {"key": None}


def _run_task(key: str, initializer, initargs, fn, index: int, task):
    """In a worker: run ``initializer(*initargs)`` once per sweep key and process, then ``fn(task)``."""
    if initializer is not None and _STATE["key"] != key:
        initializer(*initargs)
    _STATE["key"] = key
    return index, fn(task)


_BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


@contextlib.contextmanager
def _one_blas_thread():
    """Run a task with one BLAS thread, in each backend: a threaded BLAS may sum in another order with another
    thread count (and Ray gives its workers one thread), so the figures would depend on where a task ran; N
    workers with several BLAS threads each would also only contend for the cores. The libraries loaded so far
    are limited (threadpoolctl), one loaded during the task reads the environment; both are restored after."""
    from threadpoolctl import threadpool_limits

    old = {name: os.environ.get(name) for name in _BLAS_THREAD_VARIABLES}
    os.environ.update(dict.fromkeys(_BLAS_THREAD_VARIABLES, "1"))
    try:
        with threadpool_limits(1):
            yield
    finally:
        for name, value in old.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def _run_task_in_worker(key: str, initializer, initargs, fn, index: int, task):
    """:func:`_run_task` in a worker process (local or Ray), with one BLAS thread as everywhere."""
    with _one_blas_thread():
        return _run_task(key, initializer, initargs, fn, index, task)


def _start_local_worker(parent_pid: int, key: str, initializer, initargs) -> None:
    """Local worker start-up: die with the parent, then the sweep's initializer (once per process)."""
    _die_with_parent(parent_pid)
    if initializer is not None:
        with _one_blas_thread():  # as the initializer runs in this process and on Ray (inside _run_task)
            initializer(*initargs)
    _STATE["key"] = key


def _die_with_parent(parent_pid: int) -> None:
    """Local worker start-up: exit when the parent goes away, whatever way it dies."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole group: the parent decides
    die_with_parent(parent_pid, signal.SIGKILL, grace_s=0.0)  # a worker holds nothing to shut down cleanly


# ------------------------------------------------------------------------------------------ parent side
class Executor:
    """Runs a sweep's tasks (module docstring). Use as a context manager: while open, SIGINT/SIGTERM raise
    :class:`SweepInterrupted` in the main thread, and closing it stops every worker."""

    def __init__(self, options: SweepOptions = SweepOptions()):
        if not isinstance(options, SweepOptions):
            raise ValueError(f"options must be SweepOptions, got {type(options).__name__}")
        self.options = options
        self._pool: ProcessPoolExecutor | None = None
        self._pool_key: str | None = None
        self._ray = None
        self._ray_started = False
        self._old_handlers: dict = {}
        self._signum: int | None = None
        self._stop_seen = threading.Event()  #: set once the sweep has acted on the signal (workers stopping)
        self._stop_lock = threading.Lock()  #: no re-delivery after _stop_seen (the old handler may be back)
        self._task_here = False  #: a task runs in this process (the watchdog may re-deliver a signal)
        self._holding = 0  #: inside hold_stop(): a signal is recorded, raised when the block is left

    # -- lifetime ---------------------------------------------------------------------------------
    def __enter__(self) -> "Executor":
        if threading.current_thread() is threading.main_thread():
            for s in (signal.SIGINT, signal.SIGTERM):
                self._old_handlers[s] = signal.signal(s, self._on_signal)
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(kill=exc_type is not None or self._signum is not None)
        for s, h in self._old_handlers.items():
            signal.signal(s, h)
        self._old_handlers.clear()

    def _on_signal(self, signum, frame) -> None:
        if self._signum is None:  # the first signal stops the sweep
            self._signum = signum
            exit_at_once_when_done(128 + signum)  # runs first at exit, once everything is written
            threading.Thread(target=self._redeliver, name="rt2-sweep-stop", daemon=True).start()
        if self._stop_seen.is_set():  # the workers are being stopped and the partial output written: a
            return  # second signal (or a late re-delivery) must not interrupt that
        if self._holding:  # the caller writes a finished result whole (hold_stop): raised when it is done
            return
        raise SweepInterrupted(self._signum)  # again for a re-delivery: the first one may have been swallowed

    def _redeliver(self) -> None:
        """Watchdog started by the first signal: while a task runs in this process, send the signal again to
        the main thread until the sweep acts on it (module docstring: an exception raised in a signal handler
        can be dropped by the code it lands in). Outside a task, ``map``'s polls raise it again."""
        main = threading.main_thread()
        while not self._stop_seen.wait(_REDELIVER_S) and main.is_alive():
            with self._stop_lock:
                if not self._stop_seen.is_set() and self._task_here:
                    signal.pthread_kill(main.ident, self._signum)

    def _acknowledge_stop(self) -> None:
        """The sweep acts on the signal: no more re-delivery, later signals are ignored."""
        with self._stop_lock:
            self._stop_seen.set()

    def _check_signal(self) -> None:
        """Raise the pending :class:`SweepInterrupted` if a signal came and the sweep has not acted on it."""
        if self._signum is not None and not self._stop_seen.is_set():
            raise SweepInterrupted(self._signum)

    @contextlib.contextmanager
    def hold_stop(self):
        """Around the caller's handling of one finished result (a session-log record, a ball handed on): a
        signal that comes inside is recorded and raised (:class:`SweepInterrupted`) when the block is left,
        not in the middle, where it would leave the record half-written (a log that is then not finished
        cleanly). Keep the block short: the stop waits for it."""
        self._holding += 1
        try:
            yield
        finally:
            self._holding -= 1
        if not self._holding:
            self._check_signal()

    def close(self, *, kill: bool = False) -> None:
        """Stop the workers: at once (``kill``) or after their current tasks."""
        if self._signum is not None:
            self._acknowledge_stop()
        if self._pool is not None:
            if kill:
                self._kill_local()
            else:
                self._pool.shutdown(wait=True)
            self._pool = None
        if self._ray_started:
            self._ray.shutdown()
            self._ray_started = False

    def _kill_local(self) -> None:
        pool, self._pool = self._pool, None
        procs = list((getattr(pool, "_processes", None) or {}).values())
        results = getattr(pool, "_result_queue", None)  # shutdown() forgets it
        for p in procs:
            if p.is_alive():
                p.kill()
        pool.shutdown(wait=False, cancel_futures=True)
        for p in procs:
            p.join(timeout=1.0)
        # A worker killed while it wrote a result leaves half a message in the result pipe: the pool's manager
        # thread then waits in recv() for the rest forever (this process holds the pipe's write end too, so no
        # end of file comes), and the interpreter's exit joins that thread: the process never ends (seen when
        # a worker died, or on an error in a task). With every worker gone, closing our copy of the write end
        # gives the reader its end of file: the manager thread marks the pool broken and ends (not waited for
        # here: a stop by a signal leaves at once, and the interpreter's exit joins it otherwise).
        writer = getattr(results, "_writer", None)
        if writer is not None and not any(p.is_alive() for p in procs):
            try:
                writer.close()
            except OSError:
                pass

    # -- running ----------------------------------------------------------------------------------
    def map(self, fn, tasks, *, initializer=None, initargs: tuple = (), init_key: str | None = None):
        """Run ``fn(task)`` for every task; yields ``(index, result)`` as tasks finish (any order).

        init_key : map calls given the same key share each worker's ``initializer`` run (it must then be the
        same initializer and initargs); default: every call initializes afresh.
        Raises :class:`SweepInterrupted` (a signal) or :class:`WorkerLost` with the count of finished tasks,
        after stopping the workers; an exception raised by ``fn`` itself is re-raised as it is."""
        tasks = list(tasks)
        key = init_key if init_key is not None else uuid.uuid4().hex
        if self.options.ray_address is not None:
            runner = self._map_ray
        elif self.options.workers > 1 and len(tasks) > 1:
            runner = self._map_local
        else:
            runner = self._map_here
        done = 0
        try:
            for item in runner(key, fn, tasks, initializer, initargs):
                self._check_signal()
                done += 1
                yield item
                self._check_signal()  # a signal whose exception the caller's code swallowed
        except SweepInterrupted as exc:
            self._acknowledge_stop()
            self.close(kill=True)
            raise SweepInterrupted(exc.signum, done=done, total=len(tasks)) from None
        except WorkerLost as exc:
            self.close(kill=True)
            raise WorkerLost(str(exc), done=done, total=len(tasks)) from None
        except BaseException as exc:
            if self._signum is not None and _caused_by(exc, SweepInterrupted):  # the stop, wrapped by compiled code
                self._acknowledge_stop()
                self.close(kill=True)
                raise SweepInterrupted(self._signum, done=done, total=len(tasks)) from None
            self.close(kill=True)
            raise

    def _map_here(self, key, fn, tasks, initializer, initargs):
        for i, task in enumerate(tasks):
            self._check_signal()
            self._task_here = True
            try:
                with _one_blas_thread():  # as in the workers; this process's own limits come back after it
                    item = _run_task(key, initializer, initargs, fn, i, task)
            finally:
                self._task_here = False
            yield item

    def _map_local(self, key, fn, tasks, initializer, initargs):
        # The initializer and its arguments go to each process once, when it starts (not with every task:
        # a task's message stays small); a map with another initializer gets fresh processes.
        if self._pool is not None and initializer is not None and self._pool_key != key:
            self._pool.shutdown(wait=True)
            self._pool = None
        if self._pool is None:
            self._pool = ProcessPoolExecutor(max_workers=self.options.workers, mp_context=get_context("spawn"),
                                             initializer=_start_local_worker,
                                             initargs=(os.getpid(), key, initializer, initargs))
            self._pool_key = key
        pending = {self._pool.submit(_run_task_in_worker, key, None, (), fn, i, t) for i, t in enumerate(tasks)}
        dead_since: dict[int, float] = {}
        while pending:
            self._check_signal()
            finished, pending = wait(pending, timeout=_POLL_S, return_when=FIRST_COMPLETED)
            for fut in finished:
                try:
                    yield fut.result()
                except BrokenProcessPool as exc:
                    raise WorkerLost(f"a worker process died or its start-up failed ({exc})") from None
            if not finished:
                self._check_workers(dead_since)

    def _check_workers(self, dead_since: dict) -> None:
        """Raise :class:`WorkerLost` for a worker dead for a second without the pool noticing: its manager thread
        notices a dead worker at once, unless the worker died in the middle of writing a result, when that
        thread waits for the rest of the message forever (see :meth:`_kill_local`)."""
        now = time.monotonic()
        for p in list((getattr(self._pool, "_processes", None) or {}).values()):
            if p.exitcode is not None and now - dead_since.setdefault(p.pid, now) > 1.0:
                raise WorkerLost(f"a worker process died or its start-up failed (process {p.pid} exited with "
                                 f"code {p.exitcode})")

    def _connect_ray(self):
        ray = self._ray = _import_ray()
        if not ray.is_initialized():
            address = None if self.options.ray_address == "local" else self.options.ray_address
            ray.init(address=address, include_dashboard=False, logging_level="WARNING", log_to_driver=False)
            self._ray_started = True
            for s in self._old_handlers:  # ray.init installs its own SIGTERM handler (exit, nothing kept)
                signal.signal(s, self._on_signal)
        return ray

    def _map_ray(self, key, fn, tasks, initializer, initargs):
        ray = self._connect_ray()
        remote = ray.remote(num_cpus=1, max_retries=0)(_run_task_in_worker)
        init_ref = ray.put(initargs)  # shipped to each node once, not with every task
        refs = [remote.remote(key, initializer, init_ref, fn, i, t) for i, t in enumerate(tasks)]
        pending = list(refs)
        try:
            while pending:
                self._check_signal()
                ready, pending = ray.wait(pending, num_returns=1, timeout=_POLL_S)
                for ref in ready:
                    try:
                        yield ray.get(ref)
                    except ray.exceptions.RayTaskError as exc:
                        raise exc.as_instanceof_cause() from None
                    except (ray.exceptions.WorkerCrashedError, ray.exceptions.NodeDiedError,
                            ray.exceptions.RaySystemError) as exc:
                        raise WorkerLost(f"a Ray worker died ({type(exc).__name__})") from None
        finally:
            for ref in pending:
                ray.cancel(ref, force=True)
