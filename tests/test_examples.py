"""Each example scene runs (at a small size) and reproduces a number known in closed form."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import paths
import pytest
from golden import LINEAR_CANTILEVER_TIP, RELATIVE

import voxflex as vf
from voxflex.scene import Scene

EXAMPLES = paths.ROOT / "examples"


def _load(name: str) -> Scene:
    return Scene.from_toml(EXAMPLES / f"{name}.toml")


def test_every_example_parses():
    names = sorted(p.stem for p in EXAMPLES.glob("*.toml"))
    assert names == ["ball_on_plane", "cable_bar", "cantilever", "drop", "membrane_pressure", "object_image",
                     "object_mesh", "object_shape", "plastic_bar", "pushed_block", "stretch", "twist", "two_bone_limb"]
    for name in names:
        assert _load(name).probes


def test_cantilever():
    """Linear cantilever 8x2x2: -0.339310 in scikit-fem, warp.fem and sfepy (same elements and rule)."""
    result = vf.simulate(_load("cantilever"), progress=False)
    uz = result.probe_displacements()["tip"][2]
    # the reference is quoted to 6 digits; 1e-5 relative leaves room only for that rounding
    assert uz == pytest.approx(LINEAR_CANTILEVER_TIP[8], rel=RELATIVE)


def test_stretch():
    """StVK at nu = 0, stretch 1.2: uniform state, W = E/2 ((l^2 - 1)/2)^2 per unit volume."""
    scene = _load("stretch")
    result = vf.simulate(replace(scene, object=replace(scene.object, voxel_size=0.5)), progress=False)
    E, stretch = 1e4, 1.2
    energy = E / 2 * ((stretch**2 - 1) / 2) ** 2  # unit cube
    # the state is uniform (exactly representable): Newton tolerance 1e-8 on the residual
    # gives the energy to ~1e-12 relative; 1e-9 is safe
    assert result.energy_elastic[-1] == pytest.approx(energy, rel=1e-9)
    np.testing.assert_allclose(result.probes["corner"][-1], [1.2, 1.0, 1.0], atol=1e-9)


def test_twist():
    """By the half-turn symmetry about the vertical line through the bar's centre, the
    mid-section's top-edge point turns by exactly half the end rotation (22.5 degrees)."""
    scene = _load("twist")
    result = vf.simulate(replace(scene, object=replace(scene.object, voxel_size=0.5)), progress=False)
    y, z = result.probes["mid"][-1, 1] - 0.5, result.probes["mid"][-1, 2] - 0.5
    angle = math.degrees(math.atan2(-y, z))
    # exact by symmetry; the Newton tolerance (1e-8 relative residual) bounds the error ~1e-7
    assert angle == pytest.approx(22.5, abs=1e-5)
    y_end, z_end = result.probes["end"][-1, 1] - 0.5, result.probes["end"][-1, 2] - 0.5
    assert math.degrees(math.atan2(-y_end, z_end)) == pytest.approx(45.0, abs=1e-9)  # prescribed


def test_drop():
    """Backward Euler on a free fall: x_n - x_0 = g h^2 n (n + 1) / 2 exactly (no strain)."""
    scene = _load("drop")
    scene = replace(scene, object=replace(scene.object, voxel_size=0.25))
    result = vf.simulate(scene, progress=False)
    h, g, n = 0.01, -9.81, 10
    assert result.probe_displacements()["centre"][2] == pytest.approx(g * h**2 * n * (n + 1) / 2, abs=1e-12)
    assert result.probe_displacements()["centre"][2] == pytest.approx(-0.053955, abs=1e-12)


@pytest.mark.slow
def test_membrane_pressure(tmp_path):
    """Hencky's clamped circular membrane: centre deflection 0.6534 a (p a / (E h))^(1/3) (tests/hencky.py).

    Measured with this scene (q = p a / (E h) = 5e-5) at triangle edges a/4, a/8, a/16, a/32:
    -1.19e-3, -3.0e-5, +1.435e-4, +1.435e-4 relative to Hencky.  The mesh-converged membrane
    sits 1.4e-4 above Föppl-Hencky (finite strain against moderate rotations, O(q^(2/3)));
    the scene's a/8 mesh is 1.7e-4 below the converged value.  5e-4 bounds both with margin.
    """
    from hencky import hencky_deflection

    scene = _load("membrane_pressure")
    result = vf.simulate(scene, progress=False, output=tmp_path / "membrane.h5")
    w = result.probe_displacements()["centre"]
    expected = hencky_deflection(0.05, 100.0, 2.0e9, 5.0e-5, nu=0.3)
    assert w[2] == pytest.approx(expected, rel=5e-4)
    assert abs(w[0]) < 1e-12 and abs(w[1]) < 1e-12  # on the axis of symmetry
    # the render: in a subprocess (a missing GL library segfaults instead of raising, see test_render.py)
    import subprocess
    import sys

    png = tmp_path / "membrane.png"
    proc = subprocess.run([sys.executable, "-m", "voxflex", "render", str(tmp_path / "membrane.h5"), "-o", str(png)],
                          capture_output=True, text=True, timeout=300)
    if proc.returncode != 0:
        pytest.skip(f"offscreen rendering unavailable here (render exited {proc.returncode})")
    from PIL import Image

    pixels = np.asarray(Image.open(png).convert("RGB"), dtype=float)
    drawn = np.mean(np.abs(pixels - pixels[-1:, :1]).sum(axis=2) > 30)  # differs from the corner's background
    assert 0.2 < drawn < 0.9  # the disk fills a good part of the picture, not all of it
