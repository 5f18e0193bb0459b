"""Obstacles of the collision layer: signed distances with their gradients and Hessians.

An obstacle is a rigid solid the body must stay out of.  Each one answers,
for world points ``x`` (m, 3), the signed distance ``d`` (m,) to its surface
(positive outside the obstacle, metres), its gradient ``n = dd/dx`` (m, 3)
(the outward unit normal where ``d`` is a true distance) and its Hessian
``d2d/dx2`` (m, 3, 3) (1/m; the surface curvature seen from the point).
Kinds: :class:`Plane` (a half-space), :class:`Sphere`, :class:`Box` and
:class:`DistanceField` (a signed-distance image, or one computed from a label
image, trilinearly interpolated).

Every obstacle may move rigidly over a run: ``motion`` is a rigid map
``[R | t]`` (3, 4) reached at the end (load factor or time fraction 1) and
interpolated in between along the rotation vector (``R(s) = exp(s log R)``,
``t(s) = s t``), so at fraction ``s`` the obstacle occupies ``R(s) y + t(s)``
for every ``y`` of its rest shape.  The signed distance at ``x`` is the rest
shape's at ``y = R(s)^T (x - t(s))``; a rigid map keeps it a true distance
(non-rigid maps are refused for that reason).

Example
-------
>>> import numpy as np
>>> floor = Plane(point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0))
>>> d, n, H = floor.signed_distance(np.array([[0.3, 0.2, 0.5]]))
>>> float(d[0]), n[0].tolist()
(0.5, [0.0, 0.0, 1.0])
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...errors import InputError

__all__ = ["Obstacle", "Plane", "Sphere", "Box", "DistanceField", "OBSTACLE_KINDS", "OBSTACLE_KEYS", "obstacle"]

POINT_RULES = ("surface", "vertices")
"""Named collision-point rules: 2x2 Gauss points of every exposed voxel face, or the surface vertices
(an integer k gives k x k Gauss points per face)."""

OBSTACLE_KEYS = {
    "plane": ("point", "normal"),
    "sphere": ("center", "radius"),
    "box": ("min", "max"),
    "sdf": ("file",),
}
"""Each obstacle kind and the parameters it takes (``[[obstacle]]`` keys besides ``friction`` and ``motion``)."""

OBSTACLE_KINDS = tuple(OBSTACLE_KEYS)
"""``[[obstacle]] kind`` values."""

_RIGID_TOL = 1e-9  # |R^T R - I| and |det R - 1| allowed in a motion (round-off of a written rotation)


def _vec3(name, value, *, positive=False) -> np.ndarray:
    a = np.asarray(value, dtype=float)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise InputError(f"{name} must be 3 finite numbers, got {np.asarray(value).tolist()!r}")
    if positive and not np.all(a > 0):
        raise InputError(f"{name} must be > 0 along every axis, got {a.tolist()}")
    return a


def _check_motion(motion):
    if motion is None:
        return None
    T = np.asarray(motion, dtype=float)
    if T.shape != (3, 4) or not np.all(np.isfinite(T)):
        raise InputError(f"obstacle motion must be a finite 3x4 matrix [R | t], got shape {T.shape}")
    R = T[:, :3]
    if np.max(np.abs(R.T @ R - np.eye(3))) > _RIGID_TOL or abs(np.linalg.det(R) - 1.0) > _RIGID_TOL:
        raise InputError(
            "obstacle motion must be rigid (a rotation and a translation): its 3x3 part is not a rotation; "
            "a scaled or sheared obstacle has no true signed distance"
        )
    return T


@dataclass(frozen=True, eq=False)
class Obstacle:
    """Base class: friction coefficient and optional rigid motion (see the module docstring).

    Parameters
    ----------
    friction : float
        Coulomb coefficient (>= 0, finite) between the body and the obstacle;
        the contact layer (:mod:`voxflex.deform.layers.contact`) applies it.
    motion : (3, 4) float, optional
        Rigid map ``[R | t]`` reached at fraction 1 of the run.
    """

    kind = "obstacle"

    def _check_common(self):
        f = self.friction
        if isinstance(f, bool) or not isinstance(f, (int, float, np.floating)) or not np.isfinite(f) or f < 0:
            raise InputError(f"obstacle friction must be a number >= 0, got {f!r}")
        object.__setattr__(self, "friction", float(f))
        object.__setattr__(self, "motion", _check_motion(self.motion))

    def pose(self, fraction: float = 1.0):
        """Rotation R (3, 3) and translation t (3,) of the obstacle at ``fraction`` of its motion."""
        if self.motion is None:
            return np.eye(3), np.zeros(3)
        from scipy.spatial.transform import Rotation

        s = float(fraction)
        rotvec = Rotation.from_matrix(self.motion[:, :3]).as_rotvec()
        return Rotation.from_rotvec(s * rotvec).as_matrix(), s * self.motion[:, 3]

    def signed_distance(self, x, fraction: float = 0.0):
        """Signed distance of world points to the obstacle at ``fraction`` of its motion.

        Parameters
        ----------
        x : (m, 3) float, metres
        fraction : float
            Load factor (statics) or time fraction (dynamics) in [0, 1].

        Returns
        -------
        d : (m,) float, metres, positive outside
        gradient : (m, 3) float, dd/dx
        hessian : (m, 3, 3) float, d2d/dx2 (1/m)
        """
        x = np.asarray(x, dtype=float)
        if x.ndim != 2 or x.shape[1] != 3:
            raise InputError(f"points must be an (m, 3) array, got shape {x.shape}")
        return self._distance_impl(x, fraction)

    def _distance_impl(self, x, fraction):
        if self.motion is None:
            return self._local(x)
        R, t = self.pose(fraction)
        d, g, H = self._local((x - t) @ R)  # y = R^T (x - t), row-wise
        return d, g @ R.T, np.einsum("ia,mab,jb->mij", R, H, R)

    def _local(self, y):  # pragma: no cover - every kind overrides it
        raise NotImplementedError


@dataclass(frozen=True, eq=False)
class Plane(Obstacle):
    """The half-space behind a plane: ``d = (x - point) . n`` with ``n`` the unit ``normal`` (towards the body)."""

    point: tuple = (0.0, 0.0, 0.0)
    normal: tuple = (0.0, 0.0, 1.0)
    friction: float = 0.0
    motion: object = None
    kind = "plane"

    def __post_init__(self):
        object.__setattr__(self, "point", _vec3("plane point", self.point))
        n = _vec3("plane normal", self.normal)
        norm = float(np.linalg.norm(n))
        if norm == 0:
            raise InputError("plane normal must not be zero; give the direction the body lies in, e.g. [0, 0, 1]")
        object.__setattr__(self, "normal", n / norm)
        self._check_common()

    def _local(self, y):
        m = len(y)
        d = (y - self.point) @ self.normal
        return d, np.broadcast_to(self.normal, (m, 3)).copy(), np.zeros((m, 3, 3))


@dataclass(frozen=True, eq=False)
class Sphere(Obstacle):
    """A solid ball: ``d = |x - center| - radius``."""

    center: tuple = (0.0, 0.0, 0.0)
    radius: float = 1.0
    friction: float = 0.0
    motion: object = None
    kind = "sphere"

    def __post_init__(self):
        object.__setattr__(self, "center", _vec3("sphere center", self.center))
        r = self.radius
        if isinstance(r, bool) or not isinstance(r, (int, float, np.floating)) or not np.isfinite(r) or r <= 0:
            raise InputError(f"sphere radius must be a number > 0 (m), got {r!r}")
        object.__setattr__(self, "radius", float(r))
        self._check_common()

    def _local(self, y):
        p = y - self.center
        r = np.linalg.norm(p, axis=1)
        safe = np.where(r > 0, r, 1.0)
        g = p / safe[:, None]
        H = (np.eye(3)[None] - g[:, :, None] * g[:, None, :]) / safe[:, None, None]
        return r - self.radius, g, H


@dataclass(frozen=True, eq=False)
class Box(Obstacle):
    """A solid axis-aligned box [min, max] (before its motion): the exact signed distance.

    Outside, the distance to the nearest face, edge or corner (its Hessian is
    the curvature of the rounded edges and corners, zero in front of a face);
    inside, minus the distance to the nearest face.
    """

    min: tuple = (0.0, 0.0, 0.0)
    max: tuple = (1.0, 1.0, 1.0)
    friction: float = 0.0
    motion: object = None
    kind = "box"

    def __post_init__(self):
        lo = _vec3("box min", self.min)
        hi = _vec3("box max", self.max)
        if np.any(hi <= lo):
            raise InputError(f"box max must be > min along every axis, got min={lo.tolist()} max={hi.tolist()}")
        object.__setattr__(self, "min", lo)
        object.__setattr__(self, "max", hi)
        self._check_common()

    def _local(self, y):
        c = 0.5 * (self.min + self.max)
        h = 0.5 * (self.max - self.min)
        p = y - c
        s = np.where(p >= 0, 1.0, -1.0)
        q = np.abs(p) - h
        outside = np.any(q > 0, axis=1)
        qp = np.maximum(q, 0.0)
        r = np.linalg.norm(qp, axis=1)
        m = len(y)
        d = np.empty(m)
        g = np.zeros((m, 3))
        H = np.zeros((m, 3, 3))
        o = outside
        d[o] = r[o]
        g[o] = s[o] * qp[o] / r[o, None]
        act = (q[o] > 0).astype(float)
        H[o] = (act[:, :, None] * np.eye(3)[None] - g[o, :, None] * g[o, None, :]) / r[o, None, None]
        i = ~outside
        k = np.argmax(q[i], axis=1)
        d[i] = q[i][np.arange(len(k)), k]
        g[np.flatnonzero(i), k] = s[i][np.arange(len(k)), k]
        return d, g, H


@dataclass(frozen=True, eq=False)
class DistanceField(Obstacle):
    """A signed-distance image, trilinearly interpolated between voxel centres.

    Parameters
    ----------
    distance : (nx, ny, nz) float, metres
        Signed distance at the voxel centres (positive outside the obstacle);
        at least 2 voxels along every axis.
    spacing, origin : (3,) float, metres
        As for :class:`~voxflex.image.LabelImage` (``origin`` is the corner of voxel 0).
    direction : (3, 3) float
        World directions of the array axes (columns).

    Outside the box of voxel centres the distance grows by the distance to
    that box (exact for a point in front of a face of the field).  Build one
    from a label image with :meth:`from_labels`, or from a file with
    :meth:`from_file`.  Its gradient is continuous inside a cell only: with a
    coarse field, contact forces jump where points cross cell faces.
    """

    distance: np.ndarray = None
    spacing: tuple = (1.0, 1.0, 1.0)
    origin: tuple = (0.0, 0.0, 0.0)
    direction: object = None
    friction: float = 0.0
    motion: object = None
    kind = "sdf"

    def __post_init__(self):
        D = np.asarray(self.distance, dtype=float)
        if D.ndim != 3 or min(D.shape) < 2 or not np.all(np.isfinite(D)):
            raise InputError(f"a distance field needs a finite 3-D array with >= 2 voxels per axis, got shape {D.shape}")
        object.__setattr__(self, "distance", np.ascontiguousarray(D))
        spacing = _vec3("distance field spacing", self.spacing, positive=True)
        object.__setattr__(self, "spacing", spacing)
        object.__setattr__(self, "origin", _vec3("distance field origin", self.origin))
        direction = np.eye(3) if self.direction is None else np.asarray(self.direction, dtype=float)
        if direction.shape != (3, 3) or abs(abs(np.linalg.det(direction)) - 1) > 1e-6:
            raise InputError("distance field direction must be a 3x3 orthonormal matrix")
        object.__setattr__(self, "direction", direction)
        M = direction * spacing[None, :]  # world = origin + M (index), index at voxel corners
        object.__setattr__(self, "_M", M)
        object.__setattr__(self, "_Minv", np.linalg.inv(M))
        self._check_common()

    @classmethod
    def from_labels(cls, image, *, friction=0.0, motion=None) -> "DistanceField":
        """Signed distance of the occupied voxels (label > 0) of a LabelImage, by exact Euclidean distance transforms.

        Voxel centres outside get ``edt(outside) - h/2``, inside ``-(edt(inside) - h/2)``: exact for
        points in front of an axis-aligned face (``h`` the spacing across it), within half a voxel elsewhere.
        The image is padded by 2 empty voxels so the field also covers the space just around it.
        """
        from scipy.ndimage import distance_transform_edt

        mask = np.pad(np.asarray(image.labels) > 0, 2)
        if not np.any(mask):
            raise InputError("the obstacle's label image has no occupied voxel; give an image with labels > 0")
        spacing = np.asarray(image.spacing, dtype=float)
        half = 0.5 * float(spacing.min())
        out = distance_transform_edt(~mask, sampling=spacing) - half
        inside = distance_transform_edt(mask, sampling=spacing) - half
        D = np.where(mask, -inside, out)
        direction = np.asarray(image.direction, dtype=float)
        origin = np.asarray(image.origin, dtype=float) - (direction * spacing[None, :]) @ np.full(3, 2.0)
        return cls(distance=D, spacing=spacing, origin=origin, direction=direction, friction=friction, motion=motion)

    @classmethod
    def from_file(cls, path, *, friction=0.0, motion=None) -> "DistanceField":
        """A field from a file: ``.npz`` with a float array ``distance`` (and ``spacing``, ``origin``,
        optionally ``direction``) is a signed-distance image; any other image file voxflex reads is a
        label image (see :meth:`from_labels`)."""
        path = Path(path)
        if not path.is_file():
            from ...errors import missing_file

            raise missing_file(path, "obstacle file")
        if path.suffix.lower() == ".npz":
            try:
                with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:  # fh closed if np.load fails
                    if "distance" in z:
                        missing = [k for k in ("spacing", "origin") if k not in z]
                        if missing:
                            raise InputError(f"signed-distance file '{path}' lacks '{missing[0]}'; store spacing "
                                             "and origin")
                        arrays = {k: z[k] for k in ("distance", "spacing", "origin", "direction") if k in z}
                        for k, a in arrays.items():
                            if not np.issubdtype(a.dtype, np.number):
                                raise InputError(f"signed-distance file '{path}': '{k}' must be numbers, got {a.dtype}")
                        return cls(distance=arrays["distance"], spacing=arrays["spacing"], origin=arrays["origin"],
                                   direction=arrays.get("direction"), friction=friction, motion=motion)
                    if "labels" not in z:
                        found = ", ".join(repr(k) for k in z.files) or "nothing"
                        raise InputError(f"obstacle file '{path}' holds neither 'distance' (a signed-distance image "
                                         f"with spacing and origin) nor 'labels' (a label image); found {found}")
            except InputError:
                raise
            except Exception as exc:  # noqa: BLE001 - a damaged or foreign .npz (zip, pickle, CRC, truncation)
                reason = " ".join(str(exc).split())[:160] or type(exc).__name__
                raise InputError(f"obstacle file '{path}' cannot be read as a .npz signed-distance or label image "
                                 f"({reason}); write it again with numpy.savez") from None
        from ...image import LabelImage

        return cls.from_labels(LabelImage.load(path), friction=friction, motion=motion)

    def _local(self, y):
        D = self.distance
        n = np.asarray(D.shape)
        u = (y - self.origin) @ self._Minv.T - 0.5  # lattice coordinates of the voxel centres
        uc = np.clip(u, 0.0, n - 1.0)
        clamped = u != uc
        i0 = np.minimum(np.floor(uc).astype(np.int64), n - 2)
        t = uc - i0
        m = len(y)
        w = np.stack([1.0 - t, t], axis=-1)  # (m, 3, 2)
        dw = np.where(clamped, 0.0, 1.0)[:, :, None] * np.array([-1.0, 1.0])[None, None, :]
        f = np.zeros(m)
        gu = np.zeros((m, 3))
        Hu = np.zeros((m, 3, 3))
        for a in (0, 1):
            for b in (0, 1):
                for c in (0, 1):
                    v = D[i0[:, 0] + a, i0[:, 1] + b, i0[:, 2] + c]
                    wa, wb, wc = w[:, 0, a], w[:, 1, b], w[:, 2, c]
                    da, db, dc = dw[:, 0, a], dw[:, 1, b], dw[:, 2, c]
                    f += wa * wb * wc * v
                    gu[:, 0] += da * wb * wc * v
                    gu[:, 1] += wa * db * wc * v
                    gu[:, 2] += wa * wb * dc * v
                    Hu[:, 0, 1] += da * db * wc * v
                    Hu[:, 0, 2] += da * wb * dc * v
                    Hu[:, 1, 2] += wa * db * dc * v
        Hu[:, 1, 0], Hu[:, 2, 0], Hu[:, 2, 1] = Hu[:, 0, 1], Hu[:, 0, 2], Hu[:, 1, 2]
        # beyond the lattice: add the world distance to it (e = M (u - uc), r = |e|)
        e = (u - uc) @ self._M.T
        r = np.linalg.norm(e, axis=1)
        far = r > 0
        if np.any(far):
            P = clamped[far].astype(float)
            Me = e[far] @ self._M  # M^T e
            rf = r[far]
            f[far] += rf
            gu[far] += P * Me / rf[:, None]
            MtM = self._M.T @ self._M
            Hr = MtM[None] / rf[:, None, None] - Me[:, :, None] * Me[:, None, :] / rf[:, None, None] ** 3
            Hu[far] += P[:, :, None] * Hr * P[:, None, :]
        Mi = self._Minv
        return f, gu @ Mi, np.einsum("ai,mab,bj->mij", Mi, Hu, Mi)


_KIND_CLASS = {"plane": Plane, "sphere": Sphere, "box": Box, "sdf": DistanceField}


def obstacle(kind: str, **parameters) -> Obstacle:
    """An obstacle by name: ``obstacle("plane", point=..., normal=...)``, ``"sphere"`` (center, radius),
    ``"box"`` (min, max), ``"sdf"`` (``file=`` a path, or ``distance=``/``spacing=``/``origin=``);
    every kind takes ``friction`` and ``motion``."""
    from ...errors import check_choice

    check_choice("obstacle kind", kind, OBSTACLE_KINDS)
    if kind == "sdf" and "file" in parameters:
        params = dict(parameters)
        path = params.pop("file")
        unknown = sorted(set(params) - {"friction", "motion"})
        if unknown:
            raise InputError(f"obstacle kind 'sdf' with a file takes friction and motion only, got {unknown[0]!r}")
        return DistanceField.from_file(path, **params)
    cls = _KIND_CLASS[kind]
    valid = [f for f in cls.__dataclass_fields__ if not f.startswith("_")]
    for key in parameters:
        if key not in valid:
            raise InputError(f"obstacle kind '{kind}' has no parameter '{key}'; valid: {', '.join(valid)}")
    return cls(**parameters)
