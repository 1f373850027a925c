"""``rt2 log info LOG.mcap [--json] [--verify]``: what a session log holds and whether it is whole."""

from __future__ import annotations

import json
import sys

from harness.logs.reader import SessionLogReader

__all__ = ["add_arguments", "run", "format_summary"]


def add_arguments(parser) -> None:
    parser.add_argument("log", help="session log (.mcap)")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON instead of a table")
    parser.add_argument("--verify", action="store_true",
                        help="also read every chunk and check its CRC (reads the whole file); exit 1 if damaged")


def _size(n: int) -> str:
    for unit in ("B", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return str(n)


def _short(value, limit: int = 100) -> str:
    text = value if isinstance(value, str) else json.dumps(value, separators=(",", ":"))
    return text if len(text) <= limit else text[: limit - 3] + "..."


def format_summary(s, verify_problems=None) -> str:
    """The human table of ``rt2 log info`` for a :class:`~harness.logs.LogSummary`."""
    lines = [f"log         {s.path} ({_size(s.size_bytes)})"]
    sess = s.session or {}
    kind = sess.get("kind", "(not an rt2 session: no 'session' metadata)")
    extra = "  ".join(f"{k}={_short(v, 60)}" for k, v in sess.items() if k != "kind")
    lines.append(f"session     {kind}" + (f"  {extra}" if extra else ""))
    env = s.environment or {}
    if env:
        pk = env.get("packages", {})
        git = env.get("git_commit")
        git_text = f"git {git[:10]}{' (dirty)' if env.get('git_dirty') else ''}" if git else "git unknown"
        w = env.get("writer", {})
        lines.append(f"written     {env.get('created_utc', '?')} by rt2 {pk.get('rt2', '?')} ({git_text}), "
                     f"python {env.get('python', '?')}; images {w.get('image_format', '?')}, "
                     f"every {w.get('log_images_every', '?')} frame(s) (0 = none)")
    if s.finished_cleanly:
        end = s.session_end or {}
        status = "finished cleanly" + (f", but the session ended with an error: {end['error']}" if end.get("error") else "")
        dropped = {k: v for k, v in (end.get("dropped") or {}).items() if v}
        if dropped:
            status += f"; the live writer DROPPED messages: {dropped} of {end.get('submitted')}"
    else:
        status = "NOT finished cleanly: " + (s.recovery.text if s.recovery else "unknown")
    lines.append(f"status      {status}")
    comps = ", ".join(f"{k} {v}" for k, v in sorted(s.chunk_compressions.items()))
    lines.append(f"time        {s.start_s:.3f} to {s.end_s:.3f} s (duration {s.duration_s:.3f} s); "
                 f"{s.n_messages} messages in {s.n_chunks} chunks ({comps or 'none'})")
    width = max([len(t) for t in s.topics] + [5])
    swidth = max([len(v.schema) for v in s.topics.values()] + [6])
    lines.append("")
    lines.append(f"{'topic':<{width}}  {'schema':<{swidth}}  {'count':>8}  {'rate Hz':>8}")
    for topic, st in s.topics.items():
        rate = f"{st.count / s.duration_s:8.1f}" if s.duration_s > 0 else f"{'-':>8}"
        lines.append(f"{topic:<{width}}  {st.schema:<{swidth}}  {st.count:>8}  {rate}")
    lines.append("")
    lines.append(f"metadata    {', '.join(s.metadata_names) or '-'}")
    att = ", ".join(f"{n} ({m}, {_size(z)})" for n, m, z in s.attachments)
    lines.append(f"attachments {att or '-'}")
    figs = [t[len('/figures/'):] for t in s.topics if t.startswith("/figures/")]
    lines.append(f"figures     {', '.join(figs) or '-'}")
    problems = list(s.problems) + list(verify_problems or [])
    if verify_problems is not None and not verify_problems:
        lines.append("verify      every chunk read back with a matching CRC")
    for p in dict.fromkeys(problems):
        lines.append(f"problem     {p}")
    return "\n".join(lines)


def run(args) -> int:
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # problems are printed in the summary instead
        with SessionLogReader(args.log) as reader:
            summary = reader.summary()
            problems = reader.verify() if args.verify else None
    if args.json:
        doc = summary.to_dict()
        if problems is not None:
            doc["verify_problems"] = problems
        json.dump(doc, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print(format_summary(summary, problems))
    return 1 if problems else 0
