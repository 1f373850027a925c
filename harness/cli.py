"""The ``rt2`` command line.

Each command lives in its own module exposing ``add_arguments(parser)`` and ``run(args) -> int``.
Modules are imported only when their command runs, so ``rt2 --help`` stays fast and inference
commands never import torch. Bad input (``ValueError``, missing files) ends with a one-line
message naming the problem and exit code 2, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys

__all__ = ["COMMANDS", "main"]

#: command words -> (module, one-line help). Groups ("sim", "bench", ...) come from the prefixes.
COMMANDS: dict[tuple[str, ...], tuple[str, str]] = {
    ("demo",): ("harness.demo", "the main job: a short study, printed as a table"),
    ("sim", "table1"): ("harness.studies.table1", "simulation study of the robust estimator (paper Table 1)"),
    ("bench", "estimator"): ("harness.studies.bench_estimator", "run time of the robust estimator vs cameras (paper Table 2)"),
}

GROUP_HELP = {
    "sim": "simulation studies and synthetic data",
    "bench": "speed benchmarks (medians, ratios against a baseline run in the same process)",
    "eval": "evaluate a component on held-out data",
    "log": "inspect session logs",
}


def _build_parser(argv: list[str]) -> tuple[argparse.ArgumentParser, dict]:
    parser = argparse.ArgumentParser(prog="rt2", description="Reliable real-time multi-camera ball tracking.")
    top = parser.add_subparsers(dest="_cmd0", metavar="COMMAND", required=True)
    groups: dict[str, argparse._SubParsersAction] = {}
    leaves: dict[tuple[str, ...], argparse.ArgumentParser] = {}
    for words, (module, help_text) in COMMANDS.items():
        if len(words) == 1:
            leaves[words] = top.add_parser(words[0], help=help_text, description=help_text)
            continue
        group = words[0]
        if group not in groups:
            gp = top.add_parser(group, help=GROUP_HELP.get(group, ""))
            groups[group] = gp.add_subparsers(dest="_cmd1", metavar="SUBCOMMAND", required=True)
        leaves[words] = groups[group].add_parser(words[1], help=help_text, description=help_text)
    # Import and configure only the command being run.
    for words, sub in leaves.items():
        if list(words) == argv[: len(words)]:
            mod = importlib.import_module(COMMANDS[words][0])
            mod.add_arguments(sub)
            sub.set_defaults(_run=mod.run)
    return parser, leaves


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser, _ = _build_parser(argv)
    args = parser.parse_args(argv)
    cmd = " ".join(w for w in (getattr(args, "_cmd0", None), getattr(args, "_cmd1", None)) if w)
    try:
        return int(args._run(args) or 0)
    except (ValueError, FileNotFoundError, PermissionError, IsADirectoryError) as exc:
        print(f"rt2 {cmd}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"rt2 {cmd}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
