"""Shared test set-up.

* The frame-model precompute cache goes to a folder of this test session (tests never read or write
  the user's ~/.cache/voxflex).
* ``tests/support`` (the derivative contract, stand-ins, golden values, paths) is importable from every
  test folder: the tests mirror the package's layout (tests/image, tests/deform/models ...).
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("VOXFLEX_CACHE_DIR", tempfile.mkdtemp(prefix="voxflex-test-cache-"))
sys.path.insert(0, str(Path(__file__).resolve().parent / "support"))
