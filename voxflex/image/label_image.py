"""The label image: integer labels on a regular grid placed in the world.

Conventions (docs/conventions.md): ``labels[i, j, k]`` with i along x; ``spacing`` is the
voxel size along the array axes; ``origin`` is the world position of the
*corner* of voxel (0, 0, 0); ``direction`` is an orthonormal 3x3 matrix whose
columns are the world directions of the array axes.  Voxel (i, j, k) covers
``origin + direction @ (spacing * ([i, i+1] x [j, j+1] x [k, k+1]))``.

Besides geometry the image answers simple questions about its content
(label counts, volumes, bounding boxes, connected components, memory) and
describes itself in a few lines (:meth:`LabelImage.describe`, used by
``voxflex info``).  Files are read and written by :mod:`voxflex.image.io`
through :meth:`LabelImage.load` and :meth:`LabelImage.save`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError, check_choice
from .io import _as_labels, read_image, write_image

LABEL_DTYPES = (np.uint8, np.uint16)

#: Named neighbourhoods for connected components: voxels that share a face
#: (6 neighbours), a face or an edge (18), or a face, edge or corner (26).
CONNECTIVITIES = {"face": 1, "edge": 2, "vertex": 3}


def _as_vector(name, value, positive=False) -> np.ndarray:
    try:
        vec = np.broadcast_to(np.asarray(value, dtype=float), (3,)).copy()
    except (ValueError, TypeError):
        raise InputError(f"{name} must be 3 numbers, got {value!r}") from None
    if not np.all(np.isfinite(vec)):
        raise InputError(f"{name} must be finite, got {vec.tolist()}")
    if positive and np.any(vec <= 0):
        raise InputError(f"{name} must be > 0 along every axis, got {vec.tolist()}; give a positive voxel size")
    return vec


@dataclass(frozen=True, eq=False)
class LabelImage:
    """Integer labels on a regular grid placed in the world.

    Parameters
    ----------
    labels : (nx, ny, nz) integer array
        0 is empty, 1..255 (up to 65535) are materials.  Stored as uint8 or uint16.
    spacing : (3,) float, metres
        Voxel size along the array axes, > 0.
    origin : (3,) float, metres
        World position of the corner of voxel (0, 0, 0).
    direction : (3, 3) float, optional
        Orthonormal; column a is the world direction of array axis a.  Identity by default.
    occupancy : (nx, ny, nz) float array in [0, 1], optional
        Fraction of each voxel's volume occupied by material (partial volume).
    """

    labels: np.ndarray
    spacing: np.ndarray = field(default_factory=lambda: np.ones(3))
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    direction: np.ndarray = field(default_factory=lambda: np.eye(3))
    occupancy: np.ndarray | None = None

    def __post_init__(self):
        labels = _as_labels(self.labels)
        spacing = _as_vector("spacing", self.spacing, positive=True)
        origin = _as_vector("origin", self.origin)
        direction = np.asarray(self.direction, dtype=float)
        if direction.shape != (3, 3) or not np.all(np.isfinite(direction)):
            raise InputError(f"direction must be a finite 3x3 matrix, got shape {direction.shape}")
        if not np.allclose(direction.T @ direction, np.eye(3), atol=1e-6):
            raise InputError("direction must be orthonormal (columns are unit axis directions); fix the image header")
        occupancy = self.occupancy
        if occupancy is not None:
            occupancy = np.asarray(occupancy, dtype=np.float32)
            if occupancy.shape != labels.shape:
                raise InputError(f"occupancy shape {occupancy.shape} differs from labels shape {labels.shape}")
            if not np.all(np.isfinite(occupancy)) or occupancy.min() < 0 or occupancy.max() > 1 + 1e-6:
                raise InputError("occupancy fractions must lie in [0, 1]")
            occupancy = np.clip(occupancy, 0.0, 1.0)
            occupancy.setflags(write=False)
        for arr in (labels, spacing, origin, direction):
            arr.setflags(write=False)
        object.__setattr__(self, "labels", labels)
        object.__setattr__(self, "spacing", spacing)
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "direction", direction)
        object.__setattr__(self, "occupancy", occupancy)

    # -- geometry ---------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(int(s) for s in self.labels.shape)

    @property
    def voxel_volume(self) -> float:
        return float(np.prod(self.spacing))

    def index_to_world(self, index) -> np.ndarray:
        """World positions (n, 3) of continuous voxel coordinates ``index`` (n, 3).

        Integer coordinates are voxel corners; ``ijk + 0.5`` is the centre of voxel ijk.
        """
        index = np.asarray(index, dtype=float)
        return self.origin + (index * self.spacing) @ self.direction.T

    def world_to_index(self, points) -> np.ndarray:
        """Continuous voxel coordinates (n, 3) of world ``points`` (n, 3); inverse of :meth:`index_to_world`."""
        points = np.asarray(points, dtype=float)
        return ((points - self.origin) @ self.direction) / self.spacing

    def voxel_centers(self, mask=None) -> np.ndarray:
        """World centres (n, 3) of the voxels where ``mask`` is true (default: labels > 0), in C order."""
        if mask is None:
            mask = self.labels > 0
        ijk = np.argwhere(mask)
        return self.index_to_world(ijk + 0.5)

    # -- content ------------------------------------------------------------
    def present_labels(self) -> np.ndarray:
        """Sorted non-zero labels present in the image, (m,) int."""
        return np.flatnonzero(np.bincount(self.labels.ravel())[1:]) + 1

    def label_counts(self, *, include_empty: bool = False) -> dict[int, int]:
        """Number of voxels of each label present, ``{label: count}`` in increasing label order.

        Label 0 (empty) is included only when ``include_empty`` and present.
        """
        counts = np.bincount(self.labels.ravel())
        first = 0 if include_empty else 1
        return {int(lab): int(counts[lab]) for lab in np.flatnonzero(counts) if lab >= first}

    def label_volumes(self) -> dict[int, float]:
        """Material volume of each non-zero label, ``{label: m^3}``.

        With ``occupancy`` set each voxel contributes ``occupancy * voxel_volume``
        (partial volume); otherwise ``count * voxel_volume``.
        """
        flat = self.labels.ravel()
        if self.occupancy is None:
            sums = np.bincount(flat).astype(float)
        else:
            sums = np.bincount(flat, weights=self.occupancy.ravel().astype(float))
        present = np.bincount(flat)
        return {int(lab): float(sums[lab]) * self.voxel_volume for lab in np.flatnonzero(present) if lab > 0}

    def bounding_boxes(self) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """Index bounding box of each non-zero label, ``{label: (lo, hi)}``.

        ``lo`` (3,) int is the first voxel index along each axis and ``hi`` (3,)
        int is one past the last (half-open, like a slice): the label occupies
        voxels ``lo <= ijk < hi``.  In continuous index coordinates the box is
        ``[lo, hi]`` (voxel corners).
        """
        from scipy import ndimage

        boxes = {}
        for lab, slc in enumerate(ndimage.find_objects(self.labels), start=1):
            if slc is not None:
                boxes[lab] = (np.array([s.start for s in slc]), np.array([s.stop for s in slc]))
        return boxes

    def world_bounding_boxes(self) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """World axis-aligned bounding box of each non-zero label's voxels, ``{label: (min, max)}`` in m.

        The box encloses the eight corners of the label's index box mapped to
        the world (exact for an identity ``direction``; for a rotated image it
        is the world box around the rotated index box).
        """
        corners = np.array([[a, b, c] for a in (0, 1) for b in (0, 1) for c in (0, 1)], dtype=float)
        boxes = {}
        for lab, (lo, hi) in self.bounding_boxes().items():
            world = self.index_to_world(lo + corners * (hi - lo))
            boxes[lab] = (world.min(axis=0), world.max(axis=0))
        return boxes

    def connected_components(self, label: int | None = None, *, connectivity: str = "vertex"):
        """Connected components of one label (or of all material, ``label=None``).

        Parameters
        ----------
        label : int, optional
            The label whose voxels are grouped; ``None`` groups every voxel with label > 0.
        connectivity : {"vertex", "edge", "face"}
            Voxels touching by a face, edge or corner (26 neighbours), by a face
            or edge (18), or by a face only (6).

        Returns
        -------
        components : (nx, ny, nz) int32 array
            0 outside the label, 1..n the component of each voxel.
        n : int
            Number of components.
        """
        from scipy import ndimage

        check_choice("connectivity", connectivity, CONNECTIVITIES)
        mask = self.labels > 0 if label is None else self.labels == label
        structure = ndimage.generate_binary_structure(3, CONNECTIVITIES[connectivity])
        components, n = ndimage.label(mask, structure=structure)
        return components, int(n)

    def component_counts(self, *, connectivity: str = "vertex") -> dict[int, int]:
        """Number of connected components of each non-zero label present, ``{label: n}``."""
        return {
            lab: self.connected_components(lab, connectivity=connectivity)[1] for lab in self.label_counts()
        }

    @property
    def nbytes(self) -> int:
        """Memory held by the voxel arrays (labels and occupancy), in bytes."""
        return int(self.labels.nbytes + (0 if self.occupancy is None else self.occupancy.nbytes))

    # -- text ---------------------------------------------------------------
    def __repr__(self) -> str:
        shape = "x".join(str(s) for s in self.shape)
        spacing = ", ".join(f"{v:.6g}" for v in self.spacing)
        labels = self.present_labels()
        lab = ", ".join(str(v) for v in labels[:8]) + (", ..." if labels.size > 8 else "")
        occ = ", occupancy" if self.occupancy is not None else ""
        return f"LabelImage({shape} {self.labels.dtype}, spacing=[{spacing}] m, labels=[{lab}]{occ})"

    def describe(self, *, connectivity: str = "face", largest: int = 5) -> str:
        """A human-readable multi-line summary (what ``voxflex info`` prints).

        Shape, spacing, origin, direction, world extent, one line per label
        (voxels, volume, share of the material, connected parts of that label
        alone, bounding box), the connected components of the material (all
        labels together: the bodies a simulation sees) with the voxel count,
        labels and bounding box of the ``largest`` few, and the memory used.
        An image without material says so.

        Parameters
        ----------
        connectivity : {"face", "edge", "vertex"}
            Neighbourhood for the parts and components.  ``"face"`` (6
            neighbours, the default) matches mechanics: voxels that share only
            an edge or a corner form a hinge, not a joint.
        largest : int
            How many of the largest components to list (>= 0).
        """
        check_choice("connectivity", connectivity, CONNECTIVITIES)
        if int(largest) != largest or largest < 0:
            raise InputError(f"largest must be a whole number >= 0, got {largest!r}")

        def vec(v):
            return "[" + ", ".join(f"{x:.6g}" for x in v) + "]"

        nx, ny, nz = self.shape
        unit = np.array([[a, b, c] for a in (0, 1) for b in (0, 1) for c in (0, 1)], dtype=float)
        corners = self.index_to_world(unit * np.array(self.shape, dtype=float))
        identity = bool(np.allclose(self.direction, np.eye(3), atol=1e-12))
        lines = [
            f"label image {nx} x {ny} x {nz} ({self.labels.size} voxels, {self.labels.dtype})",
            f"  spacing    {vec(self.spacing)} m (voxel volume {self.voxel_volume:.6g} m^3)",
            f"  origin     {vec(self.origin)} m (corner of voxel 0,0,0)",
        ]
        if identity:
            lines.append("  direction  identity (array axes along world x, y, z)")
        else:
            rows = "; ".join(vec(r) for r in self.direction)
            lines.append(f"  direction  [{rows}] (columns: array axes in the world)")
        lines.append(f"  extent     {vec(corners.min(axis=0))} to {vec(corners.max(axis=0))} m (world box)")
        counts = self.label_counts(include_empty=True)
        material = [lab for lab in counts if lab > 0]
        if not material:
            lines.append(f"  labels     none: all {self.labels.size} voxels are 0 (empty); the image holds no material")
            lines.append(f"  memory     {_human_bytes(self.nbytes)}")
            return "\n".join(lines)
        volumes = self.label_volumes()
        total = sum(volumes.values())
        parts = self.component_counts(connectivity=connectivity)
        boxes = self.bounding_boxes()
        lines.append(
            f"  labels     {len(material)} material label(s), {counts.get(0, 0)} empty voxels"
            + (" (volumes weighted by occupancy)" if self.occupancy is not None else "")
        )
        lines.append(f"    {'label':>5} {'voxels':>10} {'volume m^3':>12} {'share':>7} {'parts':>6}  index box")
        for lab in material:
            lo_i, hi_i = boxes[lab]
            share = volumes[lab] / total if total > 0 else 0.0
            lines.append(
                f"    {lab:>5} {counts[lab]:>10} {volumes[lab]:>12.6g} {share:>7.1%} {parts[lab]:>6}  "
                f"{lo_i.tolist()} to {(hi_i - 1).tolist()}"
            )
        lines.append(f"  total      {total:.6g} m^3 of material")
        lines += self._describe_components(connectivity, int(largest))
        lines.append(f"  memory     {_human_bytes(self.nbytes)}")
        return "\n".join(lines)

    def _describe_components(self, connectivity: str, largest: int) -> list[str]:
        """Lines on the material's connected components (all labels together), largest first."""
        from scipy import ndimage

        components, n = self.connected_components(None, connectivity=connectivity)
        how = {"face": "sharing a face", "edge": "sharing a face or an edge", "vertex": "touching at all"}
        lines = [
            f"  components {n} ({connectivity} connectivity: voxels {how[connectivity]}; all labels together)"
        ]
        if n <= 1 or largest == 0:
            return lines
        sizes = np.bincount(components.ravel(), minlength=n + 1)[1:]
        order = np.argsort(-sizes, kind="stable")[:largest]
        slices = ndimage.find_objects(components)
        lines.append(f"    {'#':>5} {'voxels':>10}  {'labels':<12} index box")
        for rank, c in enumerate(order, start=1):
            slc = slices[c]
            inside = components[slc] == c + 1
            labs = np.unique(self.labels[slc][inside])
            text = ", ".join(str(v) for v in labs[:4]) + (", ..." if labs.size > 4 else "")
            lo = [s.start for s in slc]
            hi = [s.stop - 1 for s in slc]
            lines.append(f"    {rank:>5} {int(sizes[c]):>10}  {text:<12} {lo} to {hi}")
        if n > len(order):
            rest = int(sizes.sum() - sizes[order].sum())
            lines.append(f"    ... and {n - len(order)} smaller component(s) with {rest} voxels in all")
        return lines

    # -- files ----------------------------------------------------------------
    @classmethod
    def load(cls, path, *, spacing=None) -> "LabelImage":
        """Read an image file; the extension picks the format (:func:`load_image`)."""
        fields = read_image(path, spacing=spacing)
        try:
            return cls(**fields)
        except InputError as exc:
            raise InputError(f"'{Path(path).name}': {exc}") from None

    def save(self, path) -> None:
        """Write the image; the extension picks the format (:func:`save_image`)."""
        write_image(self, path)


def _human_bytes(n: int) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n} B" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n} B"  # pragma: no cover


def load_image(path, *, spacing=None) -> LabelImage:
    """Read a label image; the extension picks the format (see :mod:`voxflex.image.io`).

    Parameters
    ----------
    path : str or Path
        The image file.
    spacing : (3,) float, metres, optional
        Voxel size for files that record none (a bare ``.npy``, a plain TIFF).
        Files that record a voxel size keep it; giving a different one is an error.

    Returns
    -------
    LabelImage
        Labels as uint8/uint16, spacing and origin in metres (origin = corner of
        voxel 0), direction in voxflex's LPS world frame.

    Raises
    ------
    InputError
        Missing, unreadable or corrupt file, a file holding no image, fractional
        labels, several components per voxel, a sheared affine, an invalid or
        missing voxel size.
    """
    return LabelImage.load(path, spacing=spacing)


def save_image(image: LabelImage, path) -> None:
    """Write ``image``; the extension picks the format (see :mod:`voxflex.image.io`).

    An existing file is replaced as a whole (saving to a result ``.h5`` keeps
    only ``/image``).  The write is atomic: on failure no partial file is left and an existing
    file at ``path`` is untouched.

    Raises
    ------
    InputError
        Not a LabelImage, an unknown extension, a rotated image saved to a format without direction
        (TIFF), a missing or unwritable folder.
    """
    if not isinstance(image, LabelImage):
        raise InputError(
            f"save_image needs a LabelImage, got {type(image).__name__}; "
            "build one with LabelImage(labels, spacing, origin)"
        )
    write_image(image, path)
