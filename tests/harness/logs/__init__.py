"""Tests of harness/logs."""
