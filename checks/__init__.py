"""rt2's lowest layer: checked reading of every file we parse (``checks.files``), the array checks
of every public boundary (``checks.arrays``), and numba's disk cache checked against every file a kernel
compiles in (``checks.numba_cache``), a package's names loaded on first use (``checks.lazy``) and file names as time stamps (``checks.time_order``). Imports nothing else of rt2, so tracker/, robot_models/
and policies/ may all use it (docs/architecture.md).
"""
