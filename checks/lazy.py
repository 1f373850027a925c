"""Package attributes loaded on first use (PEP 562), for packages whose modules need different dependencies.

In ``checks/`` (the lowest layer) because every package uses it: ``tracker`` (a type such as ``FrameSet``
does not import the pipeline, OpenCV or numba), ``robot_models`` (``config``, ``limits``, ``robot_interface``
and ``joint_reference`` import without Pinocchio) and ``harness.link`` (its documented names, such as
``from harness.link import WamClient``, load on first use, so that ``python3 -m harness.link.bridge_ros``,
which runs the package's ``__init__`` first, imports under a system Python that has neither numba nor the
simulator's or the client's dependencies; docs/robot_link.md).
"""

from __future__ import annotations

from importlib import import_module

__all__ = ["lazy_attributes"]


def lazy_attributes(package: str, namespace: dict, where: dict[str, str]):
    """``(__getattr__, __dir__)`` for ``package``: name -> the module of ``package`` (``where``) that defines it.

    namespace : the package's ``globals()``; a name, once loaded, is stored there (later lookups are plain).
    """

    def __getattr__(name: str):
        module = where.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(import_module(f"{package}.{module}"), name)
        namespace[name] = value
        return value

    def __dir__():
        return sorted(set(namespace) | set(where))

    return __getattr__, __dir__
