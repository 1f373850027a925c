"""rt2 harness: simulated world, cameras and robot, experiments, logs, re-evaluation and the CLI.

The only folder allowed to import all the others (see docs/architecture.md).
"""
