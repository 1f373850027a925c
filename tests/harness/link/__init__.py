"""Tests of harness/link."""
