"""Tests of harness/experiments."""
