"""Playing sessions (``rt2 play``): served balls in closed loop through tracker, filter, hitting policy and
the simulated WAM; success rates per tracker/filter configuration (docs/play.md)."""
