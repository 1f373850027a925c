"""``python -m harness.cli ARGS`` runs ``rt2 ARGS`` (subprocesses and tests start rt2 this way)."""

import sys

from harness.cli import main

sys.exit(main())
