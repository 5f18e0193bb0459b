"""Build a rigid frame model from a scene (the affine frame model restricted to rotations)."""

from __future__ import annotations

import numpy as np

from ....errors import InputError
from ....scene import Scene
from ..frames.build import _frame_model


def _rigid_model(scene: Scene, image, materials, *, cache: bool = True):
    """Rigid frames: the affine frame model of the scene (same placement, weights, samples and
    cache) restricted to rotations (:class:`~voxflex.deform.models.rigid.model.RigidFrameModel`).

    Refused (InputError, naming the fix): dynamics (the mass in rotation coordinates depends on
    the state), obstacles, force and traction loads (their moments turn with the frames, the
    solvers hold generalised forces constant), and a moved sliding support of one component whose
    rotation is not about that axis (the frame keeps row c of R only by turning about axis c).
    """
    from .model import RigidFrameModel

    fix = 'use [nodes] kind = "affine"'
    if scene.nodes.shape_function == "reproducing-kernel":
        raise InputError('rigid frames take their reference points at the frames\' mass centres, which reproducing-'
                         'kernel weights (negative in places: some frames\' shares are negative) do not define; use '
                         f'another [nodes] shape_function, or {fix}')
    if scene.solver.kind != "static":
        raise InputError(f'rigid frames run static scenes only (their mass matrix depends on the rotation); {fix} '
                         'for dynamics')
    if scene.obstacles:
        raise InputError(f"rigid frames do not take [[obstacle]] contact yet; {fix}")
    pushed = [ld.kind for ld in scene.loads if ld.kind != "gravity"]
    if pushed:
        raise InputError(f'rigid frames take gravity loads only ([[load]] kind = "{pushed[0]}": its moment turns '
                         f"with the frames and the solver holds forces constant); {fix}")
    for i, f in enumerate(scene.fixed):
        if f.transform is None or len(f.components) != 1:
            continue
        c = "xyz".index(f.components)
        R = np.asarray(f.transform, dtype=float)[:, :3]
        if np.abs(R[c] - np.eye(3)[c]).max() > 1e-9:
            raise InputError(f'[[fixed]] #{i + 1} moves a sliding support (components = "{f.components}") by a '
                             f"rotation that is not about the {f.components} axis, which rigid frames cannot "
                             f'follow; hold more components, or {fix}')
    inner = _frame_model(scene, image, materials, cache=cache)
    densities = {int(label): float(scene.material_for(int(label)).density) for label in materials}
    return RigidFrameModel(inner, densities=densities)
