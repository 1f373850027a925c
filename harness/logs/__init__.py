"""Session logs: every experiment records its session to one MCAP file (viewable in Foxglove / Lichtblick).

Write with :class:`SessionLogWriter` (or :class:`BackgroundLogWriter` from a real-time loop), read
with :class:`SessionLogReader`; ``rt2 log info LOG.mcap`` summarises a log. Topics, schemas and the
recovery of unfinished files are documented in docs/logging.md.
"""

from harness.logs.args import add_log_arguments, open_log
from harness.logs.background import BackgroundLogWriter
from harness.logs.codecs import Detections, GroundTruthBall, JointStates
from harness.logs.reader import LogMessage, LogSummary, SessionLogReader, TopicStats
from harness.logs.topics import LogError
from harness.logs.writer import WAM_JOINT_NAMES, LogWriterOptions, SessionLogWriter, check_log_images

__all__ = [
    "BackgroundLogWriter",
    "Detections",
    "GroundTruthBall",
    "JointStates",
    "LogError",
    "LogMessage",
    "LogSummary",
    "LogWriterOptions",
    "SessionLogReader",
    "SessionLogWriter",
    "TopicStats",
    "WAM_JOINT_NAMES",
    "add_log_arguments",
    "check_log_images",
    "open_log",
]
