"""Tests of harness/common."""
