"""The same ``--log`` options for every experiment command, and opening the writer they ask for."""

from __future__ import annotations

from harness.logs.codecs import IMAGE_FORMATS
from harness.logs.writer import SessionLogWriter, check_log_images

__all__ = ["add_log_arguments", "open_log"]


def add_log_arguments(parser) -> None:
    """Add ``--log PATH``, ``--log-images all|none|N``, ``--log-image-format`` and ``--log-overwrite``."""
    g = parser.add_argument_group("session log (MCAP, see docs/logging.md)")
    g.add_argument("--log", metavar="PATH", help="record the session to this .mcap file (default: no log)")
    g.add_argument("--log-images", default="all", metavar="all|none|N",
                   help="images to record: all (default), none, or N = every N-th frame set")
    g.add_argument("--log-image-format", default="jpeg", choices=sorted(IMAGE_FORMATS),
                   help="jpeg (default, keeps up with 4 VGA cameras at 200 Hz), png (lossless, slow), raw (lossless, large)")
    g.add_argument("--log-overwrite", action="store_true", help="replace an existing log file")


def open_log(args, metadata: dict, **kwargs) -> SessionLogWriter | None:
    """A :class:`SessionLogWriter` for the parsed ``args``, or None without ``--log``.

    metadata : what the session is (``kind``, ``seed``, ``config``); kwargs go to the writer.
    """
    if not getattr(args, "log", None):
        return None
    return SessionLogWriter(args.log, metadata=metadata, log_images=check_log_images(args.log_images),
                            image_format=args.log_image_format, overwrite=args.log_overwrite, **kwargs)
