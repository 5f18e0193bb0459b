"""Voxelization: primitives and surface meshes -> one :class:`LabelImage`.

Grid placement
--------------
The image origin is the lower corner of the objects' (union) bounding box
minus ``padding`` voxels; the voxel count along axis a is
``ceil(extent_a / h_a - 1e-9) + 2 * padding`` (at least 1).  So ``box:4,1,1``
at voxel size 0.125 is exactly 32 x 8 x 8 voxels, all filled, origin 0.  When
the extent is not a multiple of the voxel size, the grid overhangs at the
upper side.

Inside rule
-----------
A voxel is material when its CENTRE is inside.  Primitives use their exact
signed distance (< 0 inside).  Meshes use the generalized winding number
(:mod:`voxflex.rasterize.winding`), inside where ``|w| > 0.5``, so that open
meshes (holes, duplicated seams) and inverted meshes voxelize sensibly.

For meshes the winding number is evaluated with the fast hierarchical method
at the corners of 4 x 4 x 4-voxel cells and, voxel by voxel, in the cells
where it may not be smooth: cells whose corner-node box the surface may meet
(found by rasterizing each triangle's bounding box, cut by its plane, into the
grid; large triangles are bisected first) and cells whose corners disagree on
the side (near a hole of an open mesh).  Every other cell has all corners on
one side and no surface between them, and takes that side.

Occupancy (``occupancy=True``)
------------------------------
Each voxel that the surface may cross (primitives: ``|sd(centre)|`` below
half the voxel diagonal; meshes: a voxel that a triangle's bounding box and
plane meet) gets the fraction of a ``k x k x k`` lattice of sub-points
(k = ``subsamples``, default 4) that lies inside; the other voxels are 0 or
1.  For meshes, w at a sub-point is w at the centre plus the signed crossings
of the segment between them with the voxel's own triangles (exact), or the
fast winding number where w at the centre is not near an integer.  The rule
for labels: a voxel is material when its occupancy is > 0 -- boundary voxels
whose centre is outside but that hold some material become material with
their fraction -- so that ``occupancy.sum() * voxel_volume`` estimates the
volume.

Several objects
---------------
A list of sources (or of ``(source, label)`` pairs) becomes ONE multi-label
image on the grid of their union bounding box.  Later entries overwrite
earlier ones where they overlap.  With occupancy, a later object takes a voxel
already held by an earlier one only where its own occupancy is >= 0.5, and
the voxel's occupancy becomes the larger of the two (a lower bound of the
union's fraction; exact for an inclusion inside a full voxel).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..image.label_image import LabelImage
from .mesh import MESH_EXTENSIONS, SurfaceMesh, as_mesh
from .primitives import PRIMITIVES, SPEC_FORMS, Box, Cylinder, Sphere, parse_spec
from .winding import DEFAULT_BETA, _fast_impl, build_tree

CELL = 4  # coarse cell size (voxels) for the winding-number evaluation away from the surface
SPLIT = 4.0  # triangles whose bounding box spans more voxels than this are bisected before rasterizing
CHUNK = 1 << 16  # points per evaluation call (progress granularity)
DEFAULT_MAX_BYTES = 4 * 1024**3


@dataclass(frozen=True)
class _Grid:
    origin: np.ndarray  # (3,) corner of voxel (0, 0, 0)
    h: np.ndarray  # (3,) voxel size
    shape: tuple[int, int, int]

    def centres(self, i0, i1) -> np.ndarray:
        """Voxel centres (n, 3) of the index box [i0, i1), C order."""
        axes = [self.origin[a] + (np.arange(i0[a], i1[a]) + 0.5) * self.h[a] for a in range(3)]
        g = np.meshgrid(*axes, indexing="ij")
        return np.stack([x.reshape(-1) for x in g], axis=1)


# -- public ------------------------------------------------------------------------
def voxelize(
    source,
    voxel_size,
    *,
    occupancy: bool = False,
    label: int = 1,
    padding: int = 0,
    max_bytes: int | None = None,
    progress: bool = True,
    subsamples: int = 4,
    beta: float = DEFAULT_BETA,
    up: str = "z",
) -> LabelImage:
    """Rasterize primitives and/or surface meshes into a label image.

    Parameters
    ----------
    source : str, Path, Box/Cylinder/Sphere, (vertices, faces) tuple, or list
        A primitive spec (``"box:LX,LY,LZ"``, ``"cylinder:R,L"``, ``"sphere:R"``;
        lower bounding-box corner at the world origin), a primitive object, a
        surface mesh file (.stl .obj .ply .vtk .vtp), a ``(vertices (V, 3),
        faces (F, 3))`` tuple, or a list of these or of ``(source, label)``
        pairs combined into one multi-label image (labels default to 1, 2, 3,
        ... in list order; later entries overwrite earlier ones where they
        overlap).
    voxel_size : float or (3,) float, metres
        Edge length(s) of a voxel, > 0.
    occupancy : bool
        Also compute the fraction of each voxel inside (``image.occupancy``);
        boundary voxels holding any material become material (see module doc).
    label : int
        Label of a single source (1..65535).
    padding : int
        Empty voxels added on every side.
    max_bytes : int, optional
        Refuse grids whose estimated working memory exceeds this; default
        min(4 GiB, half the available memory).
    progress : bool
        Show a progress bar on long work (stderr).
    subsamples : int
        k: sub-points per axis for occupancy fractions (k^3 per boundary voxel).
    beta : float
        Accuracy of the fast winding number (>= 1): a triangle cluster of
        radius r is replaced by its expansion beyond ``beta * r``.
    up : {"x", "y", "z"}
        The sources' axis that should point up: every source is first turned
        about the world origin so that this axis becomes +z
        (:func:`voxflex.rasterize.orient.turn_up`; ``"y"`` for y-up meshes),
        then the grid is placed around the turned sources.

    Returns
    -------
    LabelImage
        uint8 labels (uint16 above 255), ``spacing = voxel_size``, origin at
        the lower corner of the bounding box minus ``padding`` voxels.

    Raises
    ------
    InputError
        Bad voxel size, unknown or malformed spec, unreadable or empty mesh,
        a grid too large for memory, or a source with no voxel inside.

    Examples
    --------
    >>> image = voxelize("box:4,1,1", 0.125)
    >>> image.shape, int(image.labels.sum())
    ((32, 8, 8), 2048)
    """
    h = _voxel_size(voxel_size)
    padding = _nonneg_int("padding", padding)
    subsamples = _nonneg_int("subsamples", subsamples)
    if subsamples < 1:
        raise InputError("subsamples must be >= 1 (sub-points per axis for occupancy)")
    if not (isinstance(beta, (int, float)) and math.isfinite(beta) and beta >= 1):
        raise InputError(f"beta must be a number >= 1, got {beta!r}")
    items = _items(source, label, up)
    lo = np.min([b[0] for _, _, _, b in items], axis=0)
    hi = np.max([b[1] for _, _, _, b in items], axis=0)
    counts = np.maximum(np.ceil((hi - lo) / h - 1e-9), 1) + 2 * padding  # float: a 1e300 m box overflows int64
    _check_memory(h, counts, occupancy, max_bytes, hi - lo, padding)
    counts = counts.astype(np.int64)
    grid = _Grid(lo - padding * h, h, tuple(int(c) for c in counts))

    top = max(lab for _, lab, _, _ in items)
    labels = np.zeros(grid.shape, dtype=np.uint8 if top <= 255 else np.uint16)
    occ = np.zeros(grid.shape, dtype=np.float32) if occupancy else None
    for shape, lab, name, (blo, bhi) in items:
        i0 = np.clip(np.floor((blo - grid.origin) / h).astype(np.int64) - 1, 0, counts)
        i1 = np.clip(np.ceil((bhi - grid.origin) / h).astype(np.int64) + 1, 0, counts)
        inside, frac = _rasterize(shape, grid, i0, i1, occupancy, subsamples, beta, progress, name)
        box = tuple(slice(a, b) for a, b in zip(i0, i1))
        sub_labels = labels[box]
        if occ is None:
            if not inside.any():
                _raise_empty(name, blo, bhi, h)
            sub_labels[inside] = lab
        else:
            if not (frac > 0).any():
                _raise_empty(name, blo, bhi, h)
            sub_occ = occ[box]
            take = (frac > 0) & ((sub_labels == 0) | (frac >= 0.5))
            sub_labels[take] = lab
            sub_occ[take] = np.maximum(sub_occ[take], frac[take])
    return LabelImage(labels, spacing=h, origin=grid.origin, occupancy=occ)


# -- validation and sources ------------------------------------------------------
def _voxel_size(voxel_size) -> np.ndarray:
    if isinstance(voxel_size, (bool, np.bool_)) or (isinstance(voxel_size, (list, tuple))
                                                   and any(isinstance(v, (bool, np.bool_)) for v in voxel_size)):
        raise InputError(f"voxel size must be a number or 3 numbers (metres), got {voxel_size!r}")
    try:
        h = np.asarray(voxel_size, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"voxel size must be a number or 3 numbers (metres), got {voxel_size!r}") from None
    if h.size == 1:
        h = np.repeat(h, 3)
    if h.size != 3:
        raise InputError(f"voxel size must be 1 or 3 numbers, got {h.size}; e.g. 0.01 or 0.01,0.01,0.02")
    if not np.all(np.isfinite(h)) or np.any(h <= 0):
        raise InputError(f"voxel size must be finite and > 0, got {h.tolist()}; give a positive length in metres")
    return h


def _nonneg_int(name, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise InputError(f"{name} must be a non-negative integer, got {value!r}")
    return int(value)


def _check_label(value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 1 <= value <= 65535:
        raise InputError(f"label must be an integer in 1..65535 (0 is empty), got {value!r}")
    return int(value)


def _is_pair(item) -> bool:
    return (
        isinstance(item, tuple)
        and len(item) == 2
        and isinstance(item[1], (int, np.integer))
        and not isinstance(item[1], bool)
        and not isinstance(item[0], np.ndarray)
    )


def _items(source, label, up="z"):
    """[(shape, label, name, (lo, hi))] with shape a primitive or an oriented SurfaceMesh, turned by ``up``."""
    from .orient import turn_up, up_rotation

    up_rotation(up)  # validates the name before any file is read
    if isinstance(source, list):
        if not source:
            raise InputError("no source given; pass a mesh path, a primitive spec or a list of them")
        entries = [(s[0], s[1]) if _is_pair(s) else (s, i + 1) for i, s in enumerate(source)]
    else:
        entries = [(source, label)]
    items = []
    for src, lab in entries:
        lab = _check_label(lab)
        shape, name = _resolve(src)
        shape = turn_up(shape, up)
        items.append((shape, lab, name, tuple(np.asarray(b, dtype=float) for b in shape.bounds())))
    return items


def _resolve(src):
    if isinstance(src, (Box, Cylinder, Sphere)):
        return src, repr(src)
    if isinstance(src, SurfaceMesh):
        return src.oriented(), src.name
    if isinstance(src, (str, os.PathLike)):
        text = os.fspath(src)
        path = Path(text)
        if path.suffix.lower() in MESH_EXTENSIONS or path.exists():
            return as_mesh(path).oriented(), text
        kind, sep, _ = text.partition(":")
        if sep or kind.strip().lower() in PRIMITIVES:
            return parse_spec(text), text
        raise InputError(
            f"'{text}' is neither a mesh file ({' '.join(MESH_EXTENSIONS)}) nor a primitive spec ({SPEC_FORMS}); "
            "check the spelling or path"
        )
    if isinstance(src, tuple) and len(src) == 2:
        return as_mesh(src, name="(vertices, faces) mesh").oriented(), "(vertices, faces) mesh"
    if hasattr(src, "faces") and hasattr(src, "triangulate"):
        return as_mesh(src, name="PolyData mesh").oriented(), "PolyData mesh"
    raise InputError(
        f"cannot voxelize a {type(src).__name__}; give a mesh path, a primitive spec ({SPEC_FORMS}), "
        "a Box/Cylinder/Sphere, a (vertices, faces) tuple, or a list of these"
    )


def _available_bytes() -> int | None:
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def estimate_bytes(shape, occupancy: bool) -> int:
    """Working memory (bytes) of voxelizing on a grid of ``shape``.

    Labels (1 B) plus masks and the winding-number work arrays (about 10 B per
    voxel at the peak), plus 8 B with occupancy (the fractions and their work).
    """
    need = _need(shape, occupancy)
    return int(need) if need < 2.0**62 else 2**62


def _need(shape, occupancy: bool) -> float:
    """:func:`estimate_bytes` as a float (inf beyond double precision, as for a 1e300 m box)."""
    with np.errstate(over="ignore"):
        return float(np.prod(np.asarray(shape, dtype=float)) * (11 + (8 if occupancy else 0)))


def _check_memory(h, counts, occupancy: bool, max_bytes, extent, padding) -> None:
    """InputError naming a voxel size (or, when the padding alone is too large, a padding) that fits."""
    if max_bytes is None:
        avail = _available_bytes()
        max_bytes = DEFAULT_MAX_BYTES if avail is None else min(DEFAULT_MAX_BYTES, avail // 2)
    need = _need(counts, occupancy)
    if need <= max_bytes:
        return
    dims = "x".join(f"{c:.0f}" if c < 1e12 else f"{c:.3g}" for c in counts)
    head = f"a {dims} grid needs {'about ' if math.isfinite(need) else ''}{_human(need)} (limit {_human(max_bytes)}); "
    if estimate_bytes(np.full(3, 1.0 + 2 * padding), occupancy) > max_bytes:
        # the padding is counted in voxels: no voxel size makes it fit
        core = np.maximum(np.ceil(extent / h - 1e-9), 1)
        p = padding
        while p > 0 and estimate_bytes(core + 2 * p, occupancy) > max_bytes:
            p //= 2
        fix = f"use --padding {p} or less" if estimate_bytes(core + 2 * p, occupancy) <= max_bytes else "use --padding 0"
        raise InputError(head + f"--padding {padding} adds {2 * padding} voxels along every axis at any voxel size; {fix}")
    scale = h.max()
    per_voxel = 11 + (8 if occupancy else 0)
    fit = scale * math.exp((float(np.log(counts).sum()) + math.log(per_voxel / max_bytes)) / 3.0)  # no overflow

    def fits(size):
        return _need(np.maximum(np.ceil(extent / (h / scale * size) - 1e-9), 1) + 2 * padding, occupancy) <= max_bytes

    while not fits(fit) and fit < 1e300:  # axes one voxel thick stop shrinking: the need falls slower than cubic
        fit *= 2.0
    low = fit / 2.0
    for _ in range(60):  # the smallest size that fits, to 1e-18 of it in the log
        mid = math.exp(0.5 * (math.log(low) + math.log(fit)))
        low, fit = (low, mid) if fits(mid) else (mid, fit)
    raise InputError(head + f"use a voxel size of at least {_fmt_up(fit)} (now {_fmt(scale)})")


def _human(n: float) -> str:
    if not math.isfinite(n):
        return "more than 1e308 B"
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} B" if unit == "B" else (f"{n:.2f} {unit}" if n < 1e6 else f"{n:.3g} {unit}")
        n /= 1024
    return f"{n:.2f} GiB"  # pragma: no cover


def _fmt(x: float) -> str:
    return f"{x:.4g}"


def _fmt_up(x: float) -> str:
    if x >= 1e6:  # three digits, rounded up, as an exponent (a 1e300 m box's voxel size)
        e = int(math.floor(math.log10(x))) - 2
        return f"{math.ceil(x / 10.0**e) * 10.0**e:.3g}"
    digits = 3 - int(math.floor(math.log10(abs(x)))) - 1
    return f"{math.ceil(x * 10**digits) / 10**digits:.{max(digits, 0)}f}" if digits > 0 else f"{math.ceil(x)}"


def _raise_empty(name, lo, hi, h) -> None:
    ext = float(np.min(hi - lo))
    raise InputError(
        f"no voxel centre lies inside {name} at voxel size {_fmt(float(h.max()))}; "
        f"use a smaller voxel size (e.g. {_fmt(ext / 8)}, an eighth of its smallest extent {_fmt(ext)})"
    )


# -- rasterization of one object ------------------------------------------------------
class _Bar:
    """Progress over the winding-number evaluations (and primitive slabs)."""

    def __init__(self, enabled: bool, desc: str):
        self.enabled, self.desc, self.bar = enabled, desc, None

    def start(self, total: int):
        if self.enabled:
            from .._progress import progress

            self.bar = progress(total=total, desc=self.desc, unit="pt")
        return self

    def update(self, n: int):
        if self.bar is not None:
            self.bar.update(n)

    def set_total(self, total: int):
        if self.bar is not None:
            self.bar.total = total
            self.bar.refresh()

    def close(self):
        if self.bar is not None:
            self.bar.close()


def _rasterize(shape, grid, i0, i1, occupancy, k, beta, progress, name):
    """Inside mask (bool) and fractions (float32 or None) on the index box [i0, i1)."""
    bar = _Bar(progress, f"voxelize {Path(name).name if isinstance(shape, SurfaceMesh) else name}")
    try:
        if isinstance(shape, SurfaceMesh):
            return _mesh_impl(shape, grid, i0, i1, occupancy, k, beta, bar)
        return _primitive_impl(shape, grid, i0, i1, occupancy, k, bar)
    finally:
        bar.close()


def _sub_offsets(k: int, h: np.ndarray) -> np.ndarray:
    """(k^3, 3) offsets of a k x k x k midpoint lattice from a voxel centre."""
    t = (np.arange(k) + 0.5) / k - 0.5
    g = np.stack(np.meshgrid(t, t, t, indexing="ij"), axis=-1).reshape(-1, 3)
    return g * h


def _primitive_impl(prim, grid, i0, i1, occupancy, k, bar):
    from .primitives import _box_sd, _cylinder_sd, _sphere_sd

    sd_fn = {Box: _box_sd, Cylinder: _cylinder_sd, Sphere: _sphere_sd}[type(prim)]
    dims = tuple(int(b - a) for a, b in zip(i0, i1))
    inside = np.zeros(dims, dtype=bool)
    frac = np.zeros(dims, dtype=np.float32) if occupancy else None
    half_diag = 0.5 * float(np.linalg.norm(grid.h))
    offsets = _sub_offsets(k, grid.h) if occupancy else None
    plane = dims[1] * dims[2]
    step = max(1, CHUNK * 16 // max(plane, 1))
    bar.start(dims[0] * plane)
    for a in range(0, dims[0], step):
        b = min(dims[0], a + step)
        lo = np.array([i0[0] + a, i0[1], i0[2]])
        hi = np.array([i0[0] + b, i1[1], i1[2]])
        pts = grid.centres(lo, hi)
        sd = sd_fn(pts, prim)
        slab = sd.reshape(b - a, dims[1], dims[2]) < 0
        inside[a:b] = slab
        if occupancy:
            f = slab.astype(np.float32).reshape(-1)
            cand = np.flatnonzero(np.abs(sd) < half_diag)
            for c in range(0, len(cand), max(1, CHUNK // len(offsets))):
                idx = cand[c : c + max(1, CHUNK // len(offsets))]
                sub = (pts[idx, None, :] + offsets[None]).reshape(-1, 3)
                f[idx] = (sd_fn(sub, prim).reshape(len(idx), -1) < 0).mean(axis=1)
            frac[a:b] = f.reshape(b - a, dims[1], dims[2])
        bar.update((b - a) * plane)
    return inside, frac


def _corner_min(g: np.ndarray) -> np.ndarray:
    """(F, 3) smallest coordinates of the corners ``g`` (F, 3, 3) (elementwise: faster than a reduction)."""
    return np.minimum(np.minimum(g[:, 0], g[:, 1]), g[:, 2])


def _corner_max(g: np.ndarray) -> np.ndarray:
    """(F, 3) largest coordinates of the corners ``g`` (F, 3, 3)."""
    return np.maximum(np.maximum(g[:, 0], g[:, 1]), g[:, 2])


def _split_large(g: np.ndarray, limit: float):
    """Bisect triangles ``g`` (F, 3, 3) at their longest edge until every bounding box is <= ``limit`` per axis.

    Returns the pieces (P, 3, 3) and the index (P,) of the triangle each came from.
    """
    parent = np.arange(len(g))
    done_g, done_p = [], []
    while len(g):
        ext = _corner_max(g) - _corner_min(g)
        big = np.maximum(np.maximum(ext[:, 0], ext[:, 1]), ext[:, 2]) > limit
        done_g.append(g[~big])
        done_p.append(parent[~big])
        g, parent = g[big], parent[big]
        if not len(g):
            break
        edge = np.linalg.norm(g - np.roll(g, -1, axis=1), axis=2)  # edge c -> c + 1
        c = np.argmax(edge, axis=1)
        rows = np.arange(len(g))
        a, b, o = g[rows, c], g[rows, (c + 1) % 3], g[rows, (c + 2) % 3]
        mid = 0.5 * (a + b)
        g = np.concatenate([np.stack([a, mid, o], axis=1), np.stack([mid, b, o], axis=1)])
        parent = np.concatenate([parent, parent])
    return np.concatenate(done_g), np.concatenate(done_p)


def _surface_pairs(tri: np.ndarray, origin: np.ndarray, h: np.ndarray, dims):
    """Voxels that the triangles may meet, with the triangles of each (a conservative superset).

    Each triangle (bisected first while its bounding box spans more than
    ``SPLIT`` voxels) is rasterized by its bounding box, and the candidate
    voxels whose box its plane misses are dropped.  Both tests are
    conservative, so every voxel the surface meets is listed, with every
    triangle that meets it.

    Returns
    -------
    keys : (m,) int64
        Sorted flat ids of those voxels.
    row_ptr : (m + 1,) int64, tri_ids : int64
        CSR lists of the triangles (indices into ``tri``) of each voxel.
    """
    dims_arr = np.asarray(dims, dtype=np.int64)
    g, parent = _split_large((tri - origin) / h, SPLIT)  # voxel units: voxel ijk is the unit cube at ijk
    eps = 1e-7
    lo = np.clip(np.floor(_corner_min(g) - eps).astype(np.int64), 0, dims_arr - 1)
    hi = np.clip(np.floor(_corner_max(g) + eps).astype(np.int64), 0, dims_arr - 1)
    span = hi - lo + 1
    count = span[:, 0] * span[:, 1] * span[:, 2]
    normal = np.cross(g[:, 1] - g[:, 0], g[:, 2] - g[:, 0])
    half = (0.5 + eps) * (np.abs(normal[:, 0]) + np.abs(normal[:, 1]) + np.abs(normal[:, 2]))
    # candidates in chunks of about CHUNK * 64 (voxel, piece) pairs, to bound the work arrays
    ends = np.cumsum(count)
    budget = CHUNK * 64
    cuts = np.searchsorted(ends, np.arange(1, ends[-1] // budget + 1) * budget)
    found = []
    begin = 0
    for last in np.unique(np.append(cuts, len(g))):
        if last <= begin:
            continue
        c = count[begin:last]
        piece = begin + np.repeat(np.arange(last - begin), c)
        local = np.arange(c.sum()) - np.repeat(np.cumsum(c) - c, c)
        sy, sz = span[piece, 1], span[piece, 2]
        ijk = lo[piece] + np.stack([local // (sy * sz), (local // sz) % sy, local % sz], axis=1)
        # plane test: the unit box centred at x meets the plane n.(y - g0) = 0 iff |n.(x - g0)| <= |n|_1 / 2
        dist = np.einsum("px,px->p", normal[piece], ijk + 0.5 - g[piece, 0])
        keep = np.abs(dist) <= half[piece]
        flat = (ijk[keep, 0] * dims[1] + ijk[keep, 1]) * dims[2] + ijk[keep, 2]
        found.append(flat * len(tri) + parent[piece[keep]])
        begin = last
    pairs = np.sort(np.concatenate(found))  # by voxel, then triangle
    if len(pairs) > 1:  # pieces of one split triangle may share voxels (np.unique hashes: slow on big arrays)
        pairs = pairs[np.append(True, pairs[1:] != pairs[:-1])]
    vox, tri_ids = np.divmod(pairs, len(tri))
    first = np.flatnonzero(np.append(True, vox[1:] != vox[:-1])) if len(vox) else np.zeros(0, np.int64)
    row_ptr = np.append(first, len(vox)).astype(np.int64)
    return vox[first], row_ptr, tri_ids.astype(np.int64)


def _mesh_impl(mesh, grid, i0, i1, occupancy, k, beta, bar):
    h = grid.h
    dims = tuple(int(b - a) for a, b in zip(i0, i1))
    sub_origin = grid.origin + i0 * h
    tree = build_tree(mesh.vertices, mesh.faces)
    keys, row_ptr, tri_ids = _surface_pairs(tree.tri, sub_origin, h, dims)

    # coarse cells of CELL^3 voxels: exact evaluation where the surface may pass (dirty) or where the
    # corners disagree (near a hole of an open mesh), interpolation from the corner nodes elsewhere
    cells = tuple(-(-d // CELL) for d in dims)
    node_axes = [sub_origin[a] + (np.arange(cells[a] + 1) * CELL + 0.5) * h[a] for a in range(3)]
    nodes = np.stack([x.reshape(-1) for x in np.meshgrid(*node_axes, indexing="ij")], axis=1)
    bar.start(len(nodes) + len(keys) * CELL)  # a guess, set once the exact points are known
    w_nodes = _evaluate(tree, nodes, beta, bar).reshape(tuple(c + 1 for c in cells))
    corners = np.stack(
        [w_nodes[a : a + cells[0], b : b + cells[1], c : c + cells[2]] for a in (0, 1) for b in (0, 1) for c in (0, 1)],
        axis=-1,
    )
    all_in = np.all(corners > 0.5, axis=-1) | np.all(corners < -0.5, axis=-1)
    all_out = np.all(np.abs(corners) < 0.5, axis=-1)
    # cell c's corner nodes are the centres of voxels CELL * c and CELL * (c + 1): its node box is cell c of a
    # grid of CELL-voxel cells shifted by half a voxel; the surface may meet it where it meets that grid's cell
    touched = _surface_pairs(tree.tri, sub_origin + 0.5 * h, CELL * h, cells)[0]
    dirty = ~(all_in | all_out)
    dirty.reshape(-1)[touched] = True

    dcell = np.argwhere(dirty)  # (nd, 3)
    lattice = np.stack(np.meshgrid(*[np.arange(CELL)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    full = np.zeros(tuple(c * CELL for c in cells), dtype=bool)
    blocks = full.reshape(cells[0], CELL, cells[1], CELL, cells[2], CELL)  # a view: cell x local voxel
    # clean cells: all corners on one side, and w is smooth there (no surface): the cell takes that side
    blocks[...] = (all_in & ~dirty)[:, None, :, None, :, None]
    # dirty cells, voxel by voxel, in chunks; w is kept (cell by cell) only for the occupancy fractions
    w_dirty = np.full(len(dcell) * CELL**3, np.nan) if occupancy else None
    n_exact = int(np.minimum(np.asarray(dims) - dcell * CELL, CELL).prod(axis=1).sum())  # the grid cuts the last cells
    bar.set_total(len(nodes) + n_exact)
    per = max(1, CHUNK * 4 // CELL**3)
    for s in range(0, len(dcell), per):
        dc = dcell[s : s + per]
        vox = (dc[:, None, :] * CELL + lattice[None]).reshape(-1, 3)  # cell by cell
        valid = np.all(vox < np.asarray(dims), axis=1)
        w = np.full(len(vox), np.nan)  # NaN (outside the grid) -> outside
        w[valid] = _evaluate(tree, sub_origin + (vox[valid] + 0.5) * h, beta, bar)
        blocks[dc[:, 0], :, dc[:, 1], :, dc[:, 2], :] = (np.abs(w) > 0.5).reshape(-1, CELL, CELL, CELL)
        if occupancy:
            w_dirty[s * CELL**3 : s * CELL**3 + len(w)] = w
    inside = np.ascontiguousarray(full[: dims[0], : dims[1], : dims[2]])

    frac = None
    if occupancy:
        # w at the surface voxels' centres: already evaluated where they lie in a dirty cell (nearly all)
        rank = np.full(cells, -1, dtype=np.int64)
        rank[dcell[:, 0], dcell[:, 1], dcell[:, 2]] = np.arange(len(dcell))
        ijk = np.stack(np.unravel_index(keys, dims), axis=1)
        cell, loc = np.divmod(ijk, CELL)
        r = rank[cell[:, 0], cell[:, 1], cell[:, 2]]
        pos = r * CELL**3 + (loc[:, 0] * CELL + loc[:, 1]) * CELL + loc[:, 2]
        w_c = np.where(r >= 0, w_dirty[np.maximum(pos, 0)], np.nan)
        missing = np.flatnonzero(r < 0)
        w_c[missing] = _evaluate(tree, sub_origin + (ijk[missing] + 0.5) * h, beta, _Bar(False, ""))
        frac = inside.astype(np.float32)
        frac.reshape(-1)[keys] = _surface_fractions(tree, ijk, w_c, row_ptr, tri_ids, sub_origin, h, k, beta)
    return inside, frac


# a fixed generic shift (in voxels) so that no sub-point segment hits a mesh edge or vertex exactly
_JITTER = np.array([0.31830988618, 0.27182818284, 0.14142135623]) * 1e-6


def _surface_fractions(tree, ijk, w_c, row_ptr, tri_ids, origin, h, k, beta) -> np.ndarray:
    """Occupancy (m,) of the voxels ``ijk`` (m, 3) that the surface may meet.

    ``w_c`` is the winding number at the voxel centres.  Each of the k^3
    sub-points adds the signed crossings of the segment from the (jittered)
    centre -- exact, with the voxel's own triangles.  Where w at the centre is
    not near an integer (open meshes near holes, a centre on the surface; this
    also covers the jitter crossing the surface), the sub-points are evaluated
    with the fast winding number instead.
    """
    from .winding import _crossing_fraction_kernel

    centres = origin + (ijk + 0.5 + _JITTER) * h
    offsets = _sub_offsets(k, h)
    out = np.empty(len(ijk))
    _crossing_fraction_kernel(centres, np.ascontiguousarray(w_c), offsets, row_ptr, tri_ids, tree.tri, out)
    unsure = np.flatnonzero(np.abs(w_c - np.round(w_c)) > 0.25)
    per = max(1, (CHUNK * 4) // len(offsets))
    for s in range(0, len(unsure), per):
        idx = unsure[s : s + per]
        sub = (centres[idx, None, :] + offsets[None]).reshape(-1, 3)
        w = _evaluate(tree, sub, beta, _Bar(False, ""))
        out[idx] = (np.abs(w.reshape(len(idx), -1)) > 0.5).mean(axis=1)
    return out.astype(np.float32)


def _evaluate(tree, points, beta, bar) -> np.ndarray:
    out = np.empty(len(points))
    for s in range(0, len(points), CHUNK * 4):
        chunk = points[s : s + CHUNK * 4]
        _fast_impl(tree, chunk, beta, out[s : s + len(chunk)])
        bar.update(len(chunk))
    return out
