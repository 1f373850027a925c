"""Tests of harness/calib."""
