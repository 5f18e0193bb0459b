"""Make the pictures shown in docs/ (rerun after changing the renderer).

    python docs/make_pictures.py [NAME.png ...]

Runs the bundled default scene and three of the examples, and renders each
offscreen (EGL; no display needed) to a small PNG next to this script (only
the named pictures when names are given).  About 40 s on a 2-core machine.
"""

from __future__ import annotations

import sys
from pathlib import Path

import voxflex as vf
from voxflex.scene import Scene, default_scene_path

HERE = Path(__file__).resolve().parent
EXAMPLES = HERE.parent / "examples"
SIZE = (640, 360)

PICTURES = [
    # (file, scene, render keywords)
    ("default_scene.png", default_scene_path(), dict(view="iso")),
    ("cylinder_front.png", EXAMPLES / "object_shape.toml", dict(view="front")),
    ("capsule_mesh.png", EXAMPLES / "object_mesh.toml", dict(azimuth=30, elevation=20)),
    ("cable_bar.png", EXAMPLES / "cable_bar.toml", dict(view="front")),
]


def main(names=()) -> None:
    unknown = set(names) - {p[0] for p in PICTURES}
    if unknown:
        raise SystemExit(f"unknown picture(s) {sorted(unknown)}; valid: {[p[0] for p in PICTURES]}")
    for name, scene_path, kwargs in PICTURES:
        if names and name not in names:
            continue
        result = vf.simulate(Scene.from_toml(scene_path), progress=False)
        out = vf.render(result, HERE / name, window_size=SIZE, **kwargs)
        print(f"wrote {out} ({out.stat().st_size // 1024} kB)")


if __name__ == "__main__":
    main(sys.argv[1:])
