"""Shared utilities of every harness layer: the sweep executor, seeding, checked output paths.

Imports nothing else of harness (docs/architecture.md, the layer table)."""
