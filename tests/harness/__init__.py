"""Tests of harness/, one folder per layer."""
