"""Helpers of the robustness tests (tests/test_robustness_*.py): small scenes as TOML text, and the
contract every refused case asserts (exit status 2, one stderr line naming the problem, no traceback)."""

from __future__ import annotations

import numpy as np


def beam(kind: str = "voxel", *, size=(4.0, 1.0, 1.0), h=0.5, model="hooke", young="1.0e4", poisson="0.3",
         density="1.0", gravity="[0.0, 0.0, -9.81]", nodes="", elasticity='strain = "linear"', solver="",
         fixed_max="[1.0e-6, 1.0e9, 1.0e9]", extra="") -> str:
    """A clamped cantilever ``size`` at voxel size ``h`` under gravity (the fields are TOML values)."""
    return f"""\
[object]
shape = "box"
size = [{size[0]!r}, {size[1]!r}, {size[2]!r}]
voxel_size = {h!r}
origin = [0.0, 0.0, 0.0]

[[material]]
model = "{model}"
young = {young}
poisson = {poisson}
density = {density}

[nodes]
kind = "{kind}"
{nodes}

[elasticity]
{elasticity}

[[fixed]]
min = [-1.0e9, -1.0e9, -1.0e9]
max = {fixed_max}

[[load]]
kind = "gravity"
vector = {gravity}

[solver]
kind = "static"
{solver}

[[probe]]
name = "tip"
point = [{size[0]!r}, {size[1] / 2!r}, {size[2] / 2!r}]
{extra}"""


def image_scene(image: str, kind: str = "voxel", *, nodes="", elasticity='strain = "linear"', probe="[4.0, 0.5, 0.1]",
                fixed_max="[1.0e-6, 1.0e9, 1.0e9]", solver="") -> str:
    """A cantilever scene on an image file (a plate, two blocks ...): hooke, linear strain, gravity."""
    return f"""\
[object]
image = "{image}"

[[material]]
model = "hooke"
young = 1.0e4
poisson = 0.3
density = 1.0

[nodes]
kind = "{kind}"
{nodes}

[elasticity]
{elasticity}

[[fixed]]
min = [-1.0e9, -1.0e9, -1.0e9]
max = {fixed_max}

[[load]]
kind = "gravity"
vector = [0.0, 0.0, -9.81]

[solver]
{solver}

[[probe]]
name = "tip"
point = {probe}
"""


def assert_refused(status: int, err: str, command: str, expected) -> str:
    """Exit status 2, exactly one stderr line ``voxflex COMMAND: error: ...`` holding every ``expected``
    substring, no traceback; returns the line."""
    assert "Traceback" not in err, err
    lines = [ln for ln in err.strip().splitlines() if ": warning: " not in ln]
    assert status == 2, (status, err)
    assert len(lines) == 1, err
    line = lines[0]
    assert line.startswith(f"voxflex {command}: error: "), line
    for e in ([expected] if isinstance(expected, str) else expected):
        assert e in line, (e, line)
    return line


def tip(result, name: str = "tip") -> np.ndarray:
    """Displacement (3,) of a probe at the last state (finite, checked)."""
    p = np.asarray(result.probes[name], dtype=float)
    u = p[-1] - p[0]
    assert np.all(np.isfinite(u)), u
    return u
