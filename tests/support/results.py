"""Results and scenes several test files share: a hand-built Result, a run that fails at a known step."""

from __future__ import annotations

import numpy as np

from voxflex.result import Result


def hand_result(T: int = 3) -> Result:
    """A small Result built by hand: a unit cube (8 vertices, 12 triangles) bent a little."""
    rest = np.array([[x, y, z] for x in (0.0, 1.0) for y in (0.0, 1.0) for z in (0.0, 1.0)])
    faces = np.array(
        [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
         [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    )
    t = np.linspace(0.0, 1.0, T)
    states = np.stack([rest + s * np.c_[np.zeros(8), np.zeros(8), -0.2 * rest[:, 0]] for s in t])
    return Result(
        time=t,
        probes={"tip": states[:, 7], "base": states[:, 0]},
        surface_rest=rest,
        surface_faces=faces,
        surface_positions=states,
        nodes_rest=rest,
        nodes_state=states,
        energy_elastic=t**2,
        energy_kinetic=np.zeros(T),
        newton_iterations=np.arange(T),
        step_seconds=np.full(T, 0.01),
        image_labels=np.ones((1, 1, 1), np.uint8),
        image_spacing=(1.0, 1.0, 1.0),
        image_origin=(0.0, 0.0, 0.0),
        scene='title = "cube"\n',
    )


# A neo-Hookean bar squeezed uniformly (sliding supports) by a mirror map whose right face crosses the left
# one at load factor 0.5: with 5 steps, steps 1 and 2 (stretch 0.6 and 0.2) converge, step 3 would invert
# every voxel (neo-Hooke forbids it), so the run stops there with 2 converged steps.
SQUEEZE_SCENE = """
[object]
shape = "box"
size = [2.0, 1.0, 1.0]
voxel_size = 0.5
origin = [0.0, 0.0, 0.0]
[nodes]
kind = "voxel"
[[material]]
model = "neo-hookean"
young = 1e4
poisson = 0.3
[[fixed]]
min = [-1.0, -1.0, -1.0]
max = [0.01, 2.0, 2.0]
components = "x"
[[fixed]]
min = [-1.0, -1.0, -1.0]
max = [3.0, 0.01, 2.0]
components = "y"
[[fixed]]
min = [-1.0, -1.0, -1.0]
max = [3.0, 2.0, 0.01]
components = "z"
[[fixed]]
min = [1.99, -1.0, -1.0]
max = [3.0, 2.0, 2.0]
components = "x"
transform = [[-1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]
[solver]
steps = 5
max_iterations = 20
[[probe]]
name = "end"
point = [2.0, 0.5, 0.5]
"""
