"""numba's disk cache, checked against every file a kernel compiles in.

numba keys a cached kernel on its own source file (time stamp and size) and its own bytecode. A kernel
that calls a jitted helper from another file (``tracker/distortion.py``'s ``distort_point`` inside
``tracker/_robust_kernels.py``) has that helper compiled into it, and numba also freezes the global
constants a kernel reads: after an edit of the helper or of such a constant, numba went on loading the
old machine code from the cache, and two processes (one with a warm cache, one compiling) gave different
figures until ``make clean-numba``.

At the end of each module that defines cached kernels::

    key_cache_on_callees(globals())

adds to the cache key of every ``cache=True`` kernel of the module a digest of the source files of every
jitted function it calls, transitively (the helpers in other files included), and of the values of the
global constants they read. An edit there changes the key: the kernel is compiled afresh (and cached under
the new key) instead of being loaded stale. The digest costs a few file reads at import.
"""

from __future__ import annotations

import hashlib
import inspect
import types

__all__ = ["callee_digest", "callees", "key_cache_on_callees"]

_CONSTANT_TYPES = (bool, int, float, complex, str, bytes, type(None))


def _is_dispatcher(obj) -> bool:
    """A numba dispatcher (what ``numba.njit`` returns), recognised without importing numba."""
    return hasattr(obj, "py_func") and hasattr(obj, "targetoptions")


def _constant_text(obj) -> str | None:
    """The text standing for a constant numba would freeze into the kernel, or None for anything else."""
    if isinstance(obj, _CONSTANT_TYPES):
        return repr(obj)
    if isinstance(obj, tuple) and all(isinstance(x, _CONSTANT_TYPES) for x in obj):
        return repr(obj)
    module = type(obj).__module__
    if module == "numpy" and hasattr(obj, "dtype"):  # a numpy scalar or array
        import numpy as np

        arr = np.asarray(obj)
        return f"{arr.dtype.str}{arr.shape}:{hashlib.sha256(arr.tobytes()).hexdigest()}"
    return None


def _code_objects(code: types.CodeType):
    yield code
    for const in code.co_consts:
        if isinstance(const, types.CodeType):
            yield from _code_objects(const)


def _globals_read(func) -> dict:
    """{name: object} of the globals ``func`` reads, including ``module.name`` attributes of our modules."""
    glb, out = func.__globals__, {}
    names = {n for code in _code_objects(func.__code__) for n in code.co_names}
    for name in names:
        if name in glb:
            out[name] = glb[name]
    for obj in list(out.values()):  # `distortion.distort_point`: an attribute of an imported module
        if isinstance(obj, types.ModuleType):
            for name in names:
                if hasattr(obj, name) and not isinstance(getattr(obj, name), types.ModuleType):
                    out.setdefault(f"{obj.__name__}.{name}", getattr(obj, name))
    return out


def callees(dispatcher) -> tuple[list[str], list[str]]:
    """(source files, constants): the files of ``dispatcher`` and of every jitted function it calls,
    transitively, and ``module:name=value`` of the global constants these read; both sorted."""
    seen, todo, files, constants = set(), [dispatcher], set(), set()
    while todo:
        disp = todo.pop()
        if id(disp) in seen:
            continue
        seen.add(id(disp))
        func = disp.py_func
        files.add(inspect.getsourcefile(func) or func.__code__.co_filename)
        for name, obj in _globals_read(func).items():
            if _is_dispatcher(obj):
                todo.append(obj)
            else:
                text = _constant_text(obj)
                if text is not None:
                    constants.add(f"{func.__module__}:{name}={text}")
    return sorted(files), sorted(constants)


def callee_digest(dispatcher) -> str:
    """sha256 of the contents of :func:`callees`' files and of its constants."""
    files, constants = callees(dispatcher)
    h = hashlib.sha256()
    for path in files:
        with open(path, "rb") as f:
            h.update(hashlib.sha256(f.read()).digest())
    for text in constants:
        h.update(text.encode())
    return h.hexdigest()


def key_cache_on_callees(namespace: dict) -> list[str]:
    """Key the disk cache of each ``cache=True`` kernel defined in ``namespace`` (a module's ``globals()``) on
    :func:`callee_digest` as well; returns the names of the kernels keyed. Safe to call more than once."""
    keyed = []
    for name, obj in sorted(namespace.items()):
        if not _is_dispatcher(obj) or obj.py_func.__module__ != namespace.get("__name__"):
            continue
        cache = getattr(obj, "_cache", None)
        index_key = getattr(cache, "_index_key", None)
        if index_key is None:  # cache=False: numba's NullCache keeps nothing on disk
            continue
        if not getattr(cache, "_rt2_keyed", False):
            digest = callee_digest(obj)
            cache._index_key = lambda sig, codegen, _key=index_key, _d=digest: (*_key(sig, codegen), _d)
            cache._rt2_keyed = True
        keyed.append(name)
    return keyed
