"""Tests of harness/sim."""
