"""rt2 harness: the simulated lab, the robot link, live tracking, calibration, experiments, logs and the CLI.

The only top-level package allowed to import all the others. Inside it, layers that only import
downwards: common <- logs, sim <- link, live, calib <- experiments <- cli (docs/architecture.md).
"""
