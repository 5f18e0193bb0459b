"""A scene with every length times ``s`` and the same strains: what the same-verdict-at-every-scale tests run.

Young's moduli, densities, Poisson ratios, pressures, tractions and friction stay; gravity is divided by ``s``
(``rho g L / E`` unchanged), total forces (a ``force`` load, a cable's ``pull``) are multiplied by ``s^2``, a
cable's stiffness (N/m) by ``s``, times (``dt``) by ``s`` (the wave speed is the same), Rayleigh's mass
coefficient (1/s) divided by ``s`` and its stiffness coefficient (s) multiplied.  The translation column of a
``transform`` or ``motion`` scales, its 3x3 part does not.  Scenes that read a mesh or an image file are not
scaled here (their coordinates are in the file).
"""

from __future__ import annotations

import math
from dataclasses import replace


def _v(v, s):
    return None if v is None else tuple(x * s if math.isfinite(x) else x for x in v)


def _t(T, s):
    return None if T is None else tuple(tuple(r[:3]) + (r[3] * s,) for r in T)


def _opt(x, s):
    return None if x is None else x * s


def scaled(scene, s: float, *, kind: str | None = None):
    """``scene`` with every length times ``s`` (and ``[nodes] kind`` replaced when ``kind`` is given)."""
    o = scene.object
    if o.mesh is not None or o.image is not None:
        raise ValueError("a scene read from a mesh or image file keeps the file's coordinates; not scaled")
    nodes = scene.nodes
    if nodes.positions is not None:
        nodes = replace(nodes, positions=tuple(_v(p, s) for p in nodes.positions))
    if kind is not None:
        nodes = replace(nodes, kind=kind)
    loads = []
    for ld in scene.loads:
        f = {"gravity": 1.0 / s, "force": s * s}.get(ld.kind, 1.0)
        loads.append(replace(ld, vector=tuple(x * f for x in ld.vector), min=_v(ld.min, s), max=_v(ld.max, s)))
    contact = scene.contact
    if contact is not None and contact.distance is not None:
        contact = replace(contact, distance=contact.distance * s)
    membrane = scene.membrane
    if membrane is not None:
        membrane = replace(membrane, thickness=membrane.thickness * s)
    so = scene.solver
    return replace(
        scene,
        object=replace(o, size=_v(o.size, s), voxel_size=_opt(o.voxel_size, s), origin=_v(o.origin, s)),
        nodes=nodes,
        fixed=[replace(f, min=_v(f.min, s), max=_v(f.max, s), transform=_t(f.transform, s)) for f in scene.fixed],
        loads=type(scene.loads)(loads),
        probes=[replace(p, point=_v(p.point, s)) for p in scene.probes],
        obstacles=[replace(b, point=_v(b.point, s), center=_v(b.center, s), radius=_opt(b.radius, s),
                           min=_v(b.min, s), max=_v(b.max, s), motion=_t(b.motion, s)) for b in scene.obstacles],
        contact=contact,
        cables=[replace(c, points=tuple(_v(p, s) for p in c.points), anchor=_v(c.anchor, s), stiffness=c.stiffness * s,
                        rest_length=_opt(c.rest_length, s), shorten=_opt(c.shorten, s),
                        pull=None if c.pull is None else c.pull * s * s) for c in scene.cables],
        membrane=membrane,
        solver=replace(so, dt=so.dt * s, rayleigh_mass=so.rayleigh_mass / s, rayleigh_stiffness=so.rayleigh_stiffness * s),
    )
