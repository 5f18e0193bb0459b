"""Where the tests find the repository's files and the project's shared test meshes.

``MESHES`` is ``../shared/meshes`` beside the repository, or ``$VOXFLEX_SHARED/meshes``; it is absent in
a user's clone, and the tests that read it skip with that reason.
"""

from __future__ import annotations

import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
DATA = ROOT / "data"
SHARED = Path(os.environ.get("VOXFLEX_SHARED", ROOT.parent / "shared"))
MESHES = SHARED / "meshes"
