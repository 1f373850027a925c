"""rt2's lowest layer: checked reading of every file we parse (``checks.files``) and the array checks
of every public boundary (``checks.arrays``). Imports nothing else of rt2, so tracker/, robot_models/
and policies/ may all use it (docs/architecture.md).
"""
