"""Live tracking: camera sources, frame-set assembly, the tracking service and its publishers.

The tracker itself (``tracker/``) stays pure: no I/O, no threads of its own. Everything that talks
to cameras, sockets and the clock lives here (docs/architecture.md, docs/live.md).
"""
