"""The ROS types of ``wam_node`` for the ROS bridge: ``wam_msgs/RTJointPos``, ``wam_srvs/JointMove``, ``wam_srvs/Hold``.

Runs under the system Python with Debian's ROS packages (``python3-genpy``, ``python3-genmsg``). The
definitions ship in ``ros_defs/`` (origin and licence in ``ros_defs/README.md``); :func:`load_wam_types`
generates their Python classes with genpy into a temporary directory, or takes a lab's own
``wam_msgs`` / ``wam_srvs`` packages when they are importable (docs/robot_link.md, "ROS wam_node").
"""

from __future__ import annotations

import atexit
import importlib
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

__all__ = ["DEFINITIONS_DIR", "WamRosTypes", "load_wam_types"]

DEFINITIONS_DIR = Path(__file__).resolve().parent / "ros_defs"  #: the shipped definitions
_MESSAGES = ("RTJointPos",)
_SERVICES = ("JointMove", "Hold")


@dataclass(frozen=True)
class WamRosTypes:
    """The generated (or the lab's) classes, and where they came from (``origin``: for logs and the welcome)."""

    RTJointPos: type
    JointMove: type
    Hold: type
    origin: str


def _import_installed() -> WamRosTypes | None:
    try:
        msg = importlib.import_module("wam_msgs.msg")
        srv = importlib.import_module("wam_srvs.srv")
        return WamRosTypes(msg.RTJointPos, srv.JointMove, srv.Hold, f"installed wam_msgs ({Path(msg.__file__).parent})")
    except (ImportError, AttributeError):
        return None


def _generate(root: Path) -> WamRosTypes:
    """genpy classes from ``root/wam_msgs/msg/*.msg`` and ``root/wam_srvs/srv/*.srv`` (ROS package names kept,
    Python package names private to this process so that they never shadow a lab's own packages)."""
    from genpy.generate_initpy import write_modules
    from genpy.generator import MsgGenerator, SrvGenerator

    files = [root / "wam_msgs" / "msg" / f"{m}.msg" for m in _MESSAGES] + \
            [root / "wam_srvs" / "srv" / f"{s}.srv" for s in _SERVICES]
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        raise ValueError(f"ROS definitions not found: {missing} (expected DIR/wam_msgs/msg/*.msg, DIR/wam_srvs/srv/*.srv)")
    out = Path(tempfile.mkdtemp(prefix="rt2_wam_ros_"))
    atexit.register(shutil.rmtree, out, True)
    py_pkg = f"rt2_wam_ros_{out.name.rsplit('_', 1)[-1]}"
    for ros_pkg, sub, gen, names in (("wam_msgs", "msg", MsgGenerator(), _MESSAGES),
                                     ("wam_srvs", "srv", SrvGenerator(), _SERVICES)):
        target = out / py_pkg / ros_pkg / sub
        paths = [str(root / ros_pkg / sub / f"{n}.{sub}") for n in names]
        if gen.generate_messages(ros_pkg, paths, str(target), {}) != 0:
            raise ValueError(f"genpy could not generate {ros_pkg} from {paths} (see the messages above)")
        write_modules(str(target))
        (out / py_pkg / ros_pkg / "__init__.py").touch()
    (out / py_pkg / "__init__.py").touch()
    sys.path.insert(0, str(out))
    msg = importlib.import_module(f"{py_pkg}.wam_msgs.msg")
    srv = importlib.import_module(f"{py_pkg}.wam_srvs.srv")
    return WamRosTypes(msg.RTJointPos, srv.JointMove, srv.Hold, f"generated from {root}")


def load_wam_types(definitions: str = "auto") -> WamRosTypes:
    """The wam_node types. definitions : ``"auto"`` (the importable ``wam_msgs``/``wam_srvs`` packages, else
    the shipped definitions), ``"shipped"`` (:data:`DEFINITIONS_DIR`) or a directory laid out like it.

    Raises ValueError naming the directory or file when definitions are missing or do not generate.
    """
    if definitions == "auto":
        return _import_installed() or _generate(DEFINITIONS_DIR)
    if definitions == "shipped":
        return _generate(DEFINITIONS_DIR)
    root = Path(definitions)
    if not root.is_dir():
        raise ValueError(f"--definitions must be auto, shipped or a directory, got {definitions!r} (no such directory)")
    return _generate(root)
