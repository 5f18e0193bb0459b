"""The rigid frame kind: affine frames restricted to rotations (6 DOF each; static scenes, gravity loads)."""

from __future__ import annotations

from ....errors import InputError
from ..frames.kind import AFFINE, DEFAULT_FRAMES
from ..kinds import NodeKind

__all__ = ["RIGID", "check_scene"]


def check_scene(scene) -> None:
    """Refuse (InputError, naming the fix) what rigid frames cannot run: dynamics (the mass in rotation
    coordinates depends on the state), obstacles, force and traction loads (their moments turn with the
    frames, the solvers hold generalised forces constant), plasticity, and a moved sliding support of one
    component whose rotation is not about that axis (the frame keeps row c of R only by turning about axis c)."""
    import numpy as np

    fix = 'use [nodes] kind = "affine"'
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
    if any(m.yield_strain is not None for m in scene.materials):
        raise InputError('plasticity ([material] yield_strain) needs deformable nodes: use [nodes] kind = "affine" '
                         'or "voxel"')


RIGID = NodeKind(
    name="rigid",
    noun="rigid frame",
    plural="rigid frames",
    dofs_per_node=6,
    quadratures=AFFINE.quadratures,
    # not reproducing kernels nor eigenmodes: a rigid frame's reference point is its mass centre, which
    # negative weights (both have them) do not define
    shape_functions=tuple(s for s in AFFINE.shape_functions if s not in ("reproducing-kernel", "eigenmode")),
    description="rigid frames (6 DOF each: the mass centre, then the rotation vector); static scenes only",
    builder="voxflex.deform.models.rigid.build:build",
    estimator="voxflex.deform.models.frames.build:estimate",
    reduced=True,
    default_count=DEFAULT_FRAMES,
    static_only=True,
    takes=frozenset({"cables"}),
    check_scene="voxflex.deform.models.rigid.kind:check_scene",
)
