"""Reading and writing label images; the file's extension picks the format.

Formats
-------
=================  ==========================================  =========  =========
extension          library and layout                          direction  occupancy
=================  ==========================================  =========  =========
``.npy``           numpy; geometry in a JSON sidecar            yes        yes
                   ``NAME.npy.json`` (absent: ``spacing=`` is
                   required, origin 0, no rotation); occupancy
                   in ``NAME.occupancy.npy`` (float32)
``.npz``           numpy; ``labels``, ``spacing``, ``origin``,  yes        yes
                   ``direction``, ``occupancy`` arrays
``.nii .nii.gz``   nibabel (NIfTI-1, sform and qform set)       yes        no
``.nrrd``          pynrrd (gzip encoding)                       yes        no
``.mha .mhd``      SimpleITK (MetaImage; ``.mhd`` + ``.zraw``)  yes        no
``.tif .tiff``     tifffile; one page per z slice; geometry in  **no**     no
                   the JSON ImageDescription
``.h5 .hdf5``      h5py; group ``/image`` (dataset ``labels``,  yes        yes
                   attrs ``spacing``, ``origin``, ``direction``
                   on the group and on ``labels``,
                   optional dataset ``occupancy``)
``.vti``           pyvista/VTK XML ImageData; voxels are cells  yes        yes
=================  ==========================================  =========  =========

Formats marked "no" for occupancy store the labels only: ``save`` writes the
labels, leaves the partial-volume fractions out and warns
(:class:`OccupancyLostWarning`, naming the loss and the formats that keep
them: ``.npz``, ``.h5``, ``.vti``, ``.npy``).  TIFF cannot record a rotated image: saving an image whose
``direction`` is not the identity to TIFF raises :class:`InputError` rather
than dropping the rotation.  Labels keep their integer dtype (uint8 / uint16)
in every format.

World frame
-----------
voxflex's ``origin`` is the world position of the *corner* of voxel (0, 0, 0)
(docs/conventions.md).  NIfTI, NRRD, MetaImage and VTK point data place the *centre* of voxel
0 at their origin; readers convert with ``corner = centre - direction @
(spacing / 2)`` and writers convert back.  VTK ``.vti`` files written here store
the voxels as cells, so their origin already is the corner (dimensions =
shape + 1); a foreign ``.vti`` with point data is read with voxels centred on
its points.

For medical formats the voxflex world is **LPS** (ITK's: +x towards the
patient's left, +y posterior, +z superior).  MetaImage is LPS and is taken as
is.  NIfTI's world is RAS: readers negate the x and y rows of the affine (RAS
-> LPS) and writers negate them back, so a voxel keeps its anatomical place
when an image goes NIfTI -> voxflex -> MetaImage/NRRD.  NRRD files are converted
from their ``space`` (``right-anterior-superior`` and
``left-anterior-superior`` are flipped to LPS; ``left-posterior-superior`` and
spaces without an anatomical meaning are taken as is).  A NIfTI file with
neither sform nor qform (method 1) has no anatomical frame; its voxel
coordinates scaled by ``pixdim`` are taken as the voxflex world.  Affines with
shear or otherwise non-orthonormal directions are refused.

Units: voxflex works in metres.  Where a file states its length unit (NIfTI
``xyzt_units``, NRRD ``space units``, an ImageJ TIFF's ``unit``) the geometry is
converted to metres (``mm`` -> 1e-3 ...); where it does not (MetaImage,
NIfTI with unit "unknown", numpy, HDF5, VTK) the numbers are taken as metres.
Writers record metres where the format can (NIfTI ``meter``, NRRD ``m``).

Every file is written through :func:`voxflex._atomic.atomic_path`: a failed
write leaves no partial file and never destroys an existing one.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError, did_you_mean
from ._formats import _READERS, _WRITERS, _one_line, _spatial_array

#: extension -> format name, longest extensions first so ``.nii.gz`` wins over ``.gz``
FORMATS = {
    ".nii.gz": "NIfTI",
    ".nii": "NIfTI",
    ".npy": "NumPy",
    ".npz": "NumPy archive",
    ".nrrd": "NRRD",
    ".mha": "MetaImage",
    ".mhd": "MetaImage",
    ".tiff": "TIFF",
    ".tif": "TIFF",
    ".hdf5": "HDF5",
    ".h5": "HDF5",
    ".vti": "VTK ImageData",
}


SUPPORTED_EXTENSIONS = tuple(FORMATS)

#: formats that can record a rotated ``direction``


DIRECTION_FORMATS = ("NumPy", "NumPy archive", "NIfTI", "NRRD", "MetaImage", "HDF5", "VTK ImageData")
#: formats that store ``occupancy`` besides the labels


OCCUPANCY_FORMATS = ("NumPy", "NumPy archive", "HDF5", "VTK ImageData")


class OccupancyLostWarning(UserWarning):
    """An image with occupancy fractions was saved to a format that stores the labels only."""


def image_format(path) -> str:
    """Name of the format that ``path``'s extension selects; :class:`InputError` if none does."""
    name = Path(path).name.lower()
    for ext, fmt in FORMATS.items():
        if name.endswith(ext):
            return fmt
    suffix = "".join(Path(path).suffixes[-2:]) or "(none)"
    raise InputError(
        f"unknown image file extension '{suffix}' of '{Path(path).name}'{did_you_mean(suffix.lower(), FORMATS)}; "
        f"supported: {' '.join(SUPPORTED_EXTENSIONS)}"
    )


def read_image(path, *, spacing=None) -> dict:
    """Read a label image file into the keyword arguments of a LabelImage; the extension picks the format.

    Parameters
    ----------
    path : str or Path
        The image file.
    spacing : (3,) float, metres, optional
        Voxel size for files that record none (a bare ``.npy``, a plain TIFF).
        Files that record a voxel size keep it; giving a different one is an error.

    Returns
    -------
    dict
        ``labels`` (uint8/uint16), ``spacing`` and ``origin`` in metres (origin = corner of voxel 0),
        ``direction`` in voxflex's LPS world frame, ``occupancy`` (or None): what
        :meth:`voxflex.image.label_image.LabelImage.load` builds the image from.

    Raises
    ------
    InputError
        Missing, unreadable or corrupt file, a file holding no image, fractional
        labels, several components per voxel, a sheared affine, an invalid or
        missing voxel size.
    """
    path = Path(path)
    if not path.is_file():  # a folder is named as one, before its (missing) extension is judged
        from ..errors import missing_file

        raise missing_file(path, "image file")
    fmt = image_format(path)
    given = None
    if spacing is not None:
        given = _given_spacing(spacing)
    reader = _READERS[fmt]
    try:
        fields = reader(path)
    except InputError:
        raise
    except MemoryError:
        raise
    except Exception as exc:  # each library raises its own types for a corrupt file
        raise InputError(
            f"cannot read '{path.name}' as {fmt}: {_one_line(exc)}; check that the file is a complete {fmt} image"
        ) from None
    return _build(path, fmt, given, **fields)


def looks_like_image(path) -> bool:
    """Whether the file at ``path`` carries the signature of the format its extension names.

    A cheap check of the first bytes (no decoding), used before a file is
    overwritten: a text file or a result named ``*.nrrd`` / ``*.h5`` is not an
    image that can safely be replaced.  HDF5 files count only when they hold
    ``/image/labels`` and no ``/time`` (a simulation result is not an image file).

    Parameters
    ----------
    path : str or Path
        An existing file with an image extension.

    Returns
    -------
    bool
        False for a missing file, an unknown extension or a wrong signature.
    """
    path = Path(path)
    try:
        fmt = image_format(path)
        with open(path, "rb") as fh:
            head = fh.read(1024)
    except (InputError, OSError):
        return False
    name = path.name.lower()
    if fmt == "NumPy":
        return head.startswith(b"\x93NUMPY")
    if fmt == "NumPy archive":
        return head[:4] in (b"PK\x03\x04", b"PK\x05\x06")
    if fmt == "NIfTI":
        if name.endswith(".gz"):
            return head.startswith(b"\x1f\x8b")
        return len(head) >= 4 and (
            int.from_bytes(head[:4], "little") in (348, 540) or int.from_bytes(head[:4], "big") in (348, 540)
        )
    if fmt == "NRRD":
        return head.startswith(b"NRRD")
    if fmt == "MetaImage":
        return b"NDims" in head or b"ObjectType" in head
    if fmt == "TIFF":
        return head[:4] in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")
    if fmt == "VTK ImageData":
        return b"<VTKFile" in head and b"ImageData" in head
    if fmt == "HDF5":
        if not head.startswith(b"\x89HDF\r\n\x1a\n"):
            return False
        import h5py

        try:
            with h5py.File(str(path), "r") as f:
                return "time" not in f and isinstance(f.get("image/labels"), h5py.Dataset)
        except OSError:
            return False
    return False  # pragma: no cover - every format is listed above


def write_image(image, path) -> None:
    """Write ``image`` (a LabelImage); the extension picks the format (see the module notes).

    An existing file is replaced as a whole (saving to a result ``.h5`` keeps
    only ``/image``).  The write is atomic: on failure no partial file is left and an existing
    file at ``path`` is untouched.

    Raises
    ------
    InputError
        Unknown extension, a rotated image saved to a format without direction
        (TIFF), a missing or unwritable folder.
    """
    path = Path(path)
    fmt = image_format(path)
    if fmt not in DIRECTION_FORMATS and not _is_identity(image.direction):
        raise InputError(
            f"{fmt} cannot record the rotated direction of this image; "
            "save to .nii.gz, .nrrd, .mha, .h5, .npz or .vti instead"
        )
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise InputError(f"output folder '{folder}' does not exist; create it or choose another path")
    if image.occupancy is not None and fmt not in OCCUPANCY_FORMATS:
        import warnings

        warnings.warn(
            f"{fmt} stores the labels only: the occupancy fractions of this image are not written to "
            f"'{path.name}' (its volume becomes the full voxels'); save to .npz, .h5, .vti or .npy to keep them",
            OccupancyLostWarning,
            stacklevel=3,
        )
    try:
        _WRITERS[fmt](image, path)
    except InputError:
        raise
    except OSError as exc:
        raise InputError(
            f"cannot write '{path}': {_one_line(exc)}; check that the folder is writable and has space"
        ) from None


# -- shared helpers -----------------------------------------------------------


def _as_labels(labels) -> np.ndarray:
    arr = np.asarray(labels)
    if arr.ndim != 3:
        raise InputError(f"label image must be 3-D, got shape {arr.shape}; pass a (nx, ny, nz) array")
    if arr.size == 0:
        raise InputError(f"label image is empty (shape {arr.shape}); give at least one voxel along each axis")
    if arr.dtype == bool:
        arr = arr.astype(np.uint8)
    elif not np.issubdtype(arr.dtype, np.integer):
        if not np.issubdtype(arr.dtype, np.floating):
            raise InputError(f"label data must be integer, got dtype {arr.dtype}; convert the image to integer labels")
        if not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr)):
            raise InputError(
                "label data is not integer (fractional or NaN values); segment the image into integer labels first"
            )
    if arr.size and arr.min() < 0:
        raise InputError(f"labels must be >= 0 (0 = empty), found {arr.min()}; relabel the image")
    top = int(arr.max()) if arr.size else 0
    dtype = np.uint8 if top <= 255 else np.uint16
    if top > 65535:
        raise InputError(f"labels must be <= 65535, found {top}; relabel the image")
    return np.ascontiguousarray(arr, dtype=dtype)


def _is_identity(direction) -> bool:
    return bool(np.allclose(direction, np.eye(3), rtol=0.0, atol=1e-12))


def _given_spacing(spacing) -> np.ndarray:
    try:
        vec = np.broadcast_to(np.asarray(spacing, dtype=float), (3,)).copy()
    except (ValueError, TypeError):
        raise InputError(f"spacing must be 3 numbers (SX SY SZ, metres), got {spacing!r}") from None
    if not np.all(np.isfinite(vec)) or np.any(vec <= 0):
        raise InputError(
            f"spacing must be 3 finite numbers > 0 (metres), got {vec.tolist()}; pass a positive voxel size"
        )
    return vec


def _build(path, fmt, given, *, labels, spacing, origin=None, direction=None, occupancy=None,
           missing=None) -> dict:  # fmt: skip
    labels = _spatial_array(labels, path)
    if spacing is None:
        if given is not None:
            spacing = given
        elif missing is not None:  # a bare .npy: report bad content before asking for the spacing
            try:
                _as_labels(labels)
            except InputError as exc:
                raise InputError(f"'{path.name}': {exc}") from None
            raise InputError(
                f"'{path.name}' {missing}; pass --spacing SX SY SZ (spacing= in Python), in metres, "
                f"or write the sidecar with LabelImage(labels, spacing=...).save('{path.name}')"
            )
        else:
            raise InputError(
                f"'{path.name}' records no voxel size; pass --spacing SX SY SZ (spacing= in Python), in metres"
            )
    else:
        spacing = np.asarray(spacing, dtype=float).reshape(-1)
        if spacing.shape != (3,) or not np.all(np.isfinite(spacing)) or np.any(spacing <= 0):
            raise InputError(
                f"'{path.name}' has an invalid voxel size {spacing.tolist()} (NaN, infinite or <= 0); "
                "fix the file's header or re-export the image"
            )
        if given is not None and not np.allclose(given, spacing, rtol=1e-9, atol=0.0):
            raise InputError(
                f"'{path.name}' records voxel size {spacing.tolist()} but spacing {given.tolist()} was given; "
                "drop --spacing (it is for files without a voxel size)"
            )
    origin = np.zeros(3) if origin is None else np.asarray(origin, dtype=float).reshape(-1)
    direction = np.eye(3) if direction is None else np.asarray(direction, dtype=float)
    if origin.shape != (3,) or not np.all(np.isfinite(origin)):
        raise InputError(f"'{path.name}' has an invalid origin {origin.tolist()}; fix the file's header")
    if direction.shape != (3, 3):
        raise InputError(
            f"'{path.name}' has a direction of shape {direction.shape}, expected 3x3; fix the file's header"
        )
    return {"labels": labels, "spacing": spacing, "origin": origin, "direction": direction, "occupancy": occupancy}
