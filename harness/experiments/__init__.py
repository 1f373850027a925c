"""Experiments: accuracy, playing sessions, studies, the detector's data set, training and
evaluation, re-evaluation of session logs (docs/architecture.md, the layer table)."""
