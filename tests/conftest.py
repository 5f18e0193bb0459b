"""Shared test set-up: the frame-model precompute cache goes to a folder of this test session
(tests never read or write the user's ~/.cache/voxflex)."""

from __future__ import annotations

import os
import tempfile

os.environ.setdefault("VOXFLEX_CACHE_DIR", tempfile.mkdtemp(prefix="voxflex-test-cache-"))
