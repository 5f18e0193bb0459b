"""The image formats' readers and writers, one pair per format (see :mod:`voxflex.image.io` for the formats,
the world frame and the units).

A reader returns the fields :func:`voxflex.image.io.read_image` builds an image from (``labels``, ``spacing``,
``origin``, ``direction``, ``occupancy``); a writer writes a LabelImage through
:func:`voxflex._atomic.atomic_path`.  Each format's library is imported when it is first used
(:func:`_require` names the extra that installs it).
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np

from .._atomic import atomic_path
from ..errors import InputError


def _require(module: str, what: str):
    """Import a format's reader, or say which extra installs it."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError:
        raise InputError(
            f"{what} files need the '{module}' package; install it with: pip install 'voxflex[images]'"
        ) from None


_LPS_FROM_RAS = np.diag([-1.0, -1.0, 1.0])


_ORTHO_TOL = 1e-4  # NIfTI stores its affine in float32: allow ~1e-7 noise, refuse real shear


_UNITS = {
    "m": 1.0, "meter": 1.0, "meters": 1.0, "metre": 1.0, "metres": 1.0,
    "cm": 1e-2, "centimeter": 1e-2,
    "mm": 1e-3, "millimeter": 1e-3, "millimetre": 1e-3,
    "um": 1e-6, "µm": 1e-6, "\u03bcm": 1e-6, "micron": 1e-6, "microns": 1e-6, "micrometer": 1e-6,
    "nm": 1e-9, "nanometer": 1e-9,
}  # fmt: skip


# -- shared helpers -----------------------------------------------------------


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 200 else text[:197] + "..."


def _unit_scale(unit, where: str) -> float:
    key = str(unit).strip().lower()
    if key not in _UNITS:
        raise InputError(f"unknown length unit '{unit}' in {where}; valid: {', '.join(sorted(set(_UNITS)))}")
    return _UNITS[key]


def _spatial_array(arr, path, axes=None) -> np.ndarray:
    """Reduce a file's array to 3-D: extra axes of size 1 are dropped; more components are an error."""
    arr = np.asarray(arr)
    if arr.ndim < 3:
        raise InputError(
            f"'{path.name}' holds a {arr.ndim}-D array of shape {arr.shape}; voxflex needs a 3-D label volume"
        )
    if arr.ndim > 3:
        extra = arr.shape[3:]
        if int(np.prod(extra)) != 1:
            raise InputError(
                f"'{path.name}' has {int(np.prod(extra))} components per voxel (shape {arr.shape}); "
                "a label image has one: extract the label channel first"
            )
        arr = arr.reshape(arr.shape[:3])
    return arr


def _frame_from_centre_affine(matrix, centre, path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(spacing, corner origin, direction) from axis vectors ``matrix`` (columns) and voxel 0's centre."""
    matrix = np.asarray(matrix, dtype=float)
    centre = np.asarray(centre, dtype=float)
    if not (np.all(np.isfinite(matrix)) and np.all(np.isfinite(centre))):
        raise InputError(
            f"'{path.name}' has NaN or infinite spacing/origin in its header; fix the header or re-export the image"
        )
    spacing = np.linalg.norm(matrix, axis=0)
    if np.any(spacing <= 0):
        raise InputError(
            f"'{path.name}' has a zero voxel size {spacing.tolist()}; fix the header or re-export the image"
        )
    direction = matrix / spacing
    if not np.allclose(direction.T @ direction, np.eye(3), atol=_ORTHO_TOL):
        raise InputError(
            f"'{path.name}' has a sheared or non-orthogonal affine; "
            "voxflex needs orthogonal voxel axes: resample the image"
        )
    u, _, vt = np.linalg.svd(direction)  # nearest orthonormal matrix (float32 headers carry ~1e-7 noise)
    direction = u @ vt
    origin = centre - direction @ (spacing / 2.0)
    return spacing, origin, direction


def _centre_affine(image) -> tuple[np.ndarray, np.ndarray]:
    """Axis vectors (columns, 3x3) and the centre of voxel 0 of ``image``."""
    matrix = image.direction * image.spacing
    return matrix, image.origin + matrix @ np.full(3, 0.5)


# -- NumPy ----------------------------------------------------------------------
_SIDECAR_KIND = "voxflex-label-image-geometry"


def _sidecar(path: Path) -> Path:
    return path.with_name(path.name + ".json")


def _check_magic(path, magic: bytes, what: str):
    with open(path, "rb") as fh:
        head = fh.read(len(magic))
    if head != magic:
        raise InputError(f"'{path.name}' is not a {what} file (wrong signature); check the file or its extension")


def _read_npy(path):
    _check_magic(path, b"\x93NUMPY", "NumPy .npy")
    with open(path, "rb") as fh:
        labels = np.load(fh, allow_pickle=False)
    side = _sidecar(path)
    if not side.exists():
        # a bare array records no geometry: the caller gives the spacing or the read is refused
        return dict(labels=labels, spacing=None, missing=f"has no sidecar '{side.name}' recording its voxel size")
    try:
        meta = json.loads(side.read_text())
        geometry = {key: np.asarray(meta[key], dtype=float) for key in ("spacing", "origin", "direction")}
    except (ValueError, KeyError, TypeError) as exc:
        raise InputError(
            f"sidecar '{side.name}' is not valid voxflex geometry JSON ({_one_line(exc)}); fix or delete it"
        ) from None
    out = dict(labels=labels, **geometry)
    occ = meta.get("occupancy")
    if occ is not None:
        occ_path = path.with_name(str(occ))
        if occ_path.name != str(occ) or not occ_path.exists():
            raise InputError(f"sidecar '{side.name}' names the occupancy file '{occ}', which is missing; "
                             "restore it or delete the 'occupancy' entry")
        with open(occ_path, "rb") as fh:
            out["occupancy"] = np.load(fh, allow_pickle=False)
    return out


def _occupancy_sidecar(path: Path) -> Path:
    name = path.name
    return path.with_name((name[:-4] if name.lower().endswith(".npy") else name) + ".occupancy.npy")


def _write_npy(image, path):
    meta = {
        "kind": _SIDECAR_KIND,
        "units": "m",
        "spacing": image.spacing.tolist(),
        "origin": image.origin.tolist(),
        "direction": image.direction.tolist(),
        "note": "origin is the corner of voxel (0,0,0); direction columns are the array axes in the world",
    }
    if image.occupancy is None:
        with atomic_path(path) as tmp, atomic_path(_sidecar(path)) as tmp_side:
            with open(tmp, "wb") as fh:
                np.save(fh, image.labels, allow_pickle=False)
            Path(tmp_side).write_text(json.dumps(meta, indent=1) + "\n")
        return
    occ_path = _occupancy_sidecar(path)
    meta["occupancy"] = occ_path.name  # partial-volume fractions (float32) in a second array beside it
    with atomic_path(path) as tmp, atomic_path(_sidecar(path)) as tmp_side, atomic_path(occ_path) as tmp_occ:
        with open(tmp, "wb") as fh:
            np.save(fh, image.labels, allow_pickle=False)
        with open(tmp_occ, "wb") as fh:
            np.save(fh, np.asarray(image.occupancy, dtype=np.float32), allow_pickle=False)
        Path(tmp_side).write_text(json.dumps(meta, indent=1) + "\n")


def _read_npz(path):
    _check_magic(path, b"PK", "NumPy .npz (zip)")
    with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as data:
        if "labels" not in data.files:
            found = ", ".join(data.files) or "nothing"
            raise InputError(f"'{path.name}' has no 'labels' array (found {found}); it is not a voxflex image")
        out = dict(labels=data["labels"], spacing=data["spacing"] if "spacing" in data.files else None)
        for key in ("origin", "direction", "occupancy"):
            if key in data.files:
                out[key] = data[key]
    return out


def _write_npz(image, path):
    arrays = dict(labels=image.labels, spacing=image.spacing, origin=image.origin, direction=image.direction)
    if image.occupancy is not None:
        arrays["occupancy"] = image.occupancy
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, **arrays)


# -- NIfTI ------------------------------------------------------------------------


def _read_nifti(path):
    nib = _require("nibabel", "NIfTI")

    img = nib.load(str(path))
    if not isinstance(img, (nib.Nifti1Image, nib.Nifti2Image)):
        raise InputError(f"'{path.name}' is not a NIfTI image; check the file")
    header = img.header
    labels = _spatial_array(np.asarray(img.dataobj), path)
    unit = header.get_xyzt_units()[0]
    scale = 1.0 if unit == "unknown" else _unit_scale(unit, f"'{path.name}'")
    if int(header["sform_code"]) > 0 or int(header["qform_code"]) > 0:
        affine = np.asarray(img.affine, dtype=float)  # RAS, maps voxel centres
        matrix = _LPS_FROM_RAS @ affine[:3, :3]
        centre = _LPS_FROM_RAS @ affine[:3, 3]
    else:  # method 1: no anatomical frame, coordinates = index * pixdim
        matrix = np.diag(np.asarray(header.get_zooms()[:3], dtype=float))
        centre = np.zeros(3)
    spacing, origin, direction = _frame_from_centre_affine(matrix * scale, centre * scale, path)
    return dict(labels=labels, spacing=spacing, origin=origin, direction=direction)


def _write_nifti(image, path):
    nib = _require("nibabel", "NIfTI")

    matrix, centre = _centre_affine(image)
    affine = np.eye(4)
    affine[:3, :3] = _LPS_FROM_RAS @ matrix
    affine[:3, 3] = _LPS_FROM_RAS @ centre
    img = nib.Nifti1Image(image.labels, affine)
    img.set_sform(affine, code="scanner")
    img.set_qform(affine, code="scanner")
    img.header.set_xyzt_units(xyz="meter")
    with atomic_path(path) as tmp:
        nib.save(img, str(tmp))


# -- NRRD -------------------------------------------------------------------------


_NRRD_SPACES = {
    "left-posterior-superior": (1.0, 1.0, 1.0),
    "lps": (1.0, 1.0, 1.0),
    "right-anterior-superior": (-1.0, -1.0, 1.0),
    "ras": (-1.0, -1.0, 1.0),
    "left-anterior-superior": (1.0, -1.0, 1.0),
    "las": (1.0, -1.0, 1.0),
}


def _read_nrrd(path):
    nrrd = _require("nrrd", "NRRD")

    data, header = nrrd.read(str(path), index_order="F")
    data = np.asarray(data)
    directions = header.get("space directions")
    if directions is not None:
        directions = np.asarray(directions, dtype=float)
        spatial = ~np.all(np.isnan(directions), axis=1)  # 'none' rows mark component axes
        if np.count_nonzero(spatial) != 3 or directions.shape[1] != 3:
            raise InputError(
                f"'{path.name}' has {np.count_nonzero(spatial)} spatial axes in a {directions.shape[1]}-D space; "
                "voxflex needs a 3-D volume"
            )
        others = [ax for ax in range(data.ndim) if not spatial[ax]]
        n_comp = int(np.prod([data.shape[ax] for ax in others])) if others else 1
        if n_comp != 1:
            raise InputError(
                f"'{path.name}' has {n_comp} components per voxel (shape {data.shape}); "
                "a label image has one: extract the label channel first"
            )
        data = np.moveaxis(data, [ax for ax in range(data.ndim) if spatial[ax]], [0, 1, 2]).reshape(
            [data.shape[ax] for ax in range(data.ndim) if spatial[ax]]
        )
        space = str(header.get("space", "")).strip().lower()
        signs = np.asarray(_NRRD_SPACES.get(space, (1.0, 1.0, 1.0)))
        matrix = signs[:, None] * directions[spatial].T  # columns = axis vectors
        centre = signs * np.asarray(header.get("space origin", np.zeros(3)), dtype=float)
        scale = 1.0
        units = header.get("space units")
        if units is not None:
            units = [str(u) for u in units]
            if len(set(units)) != 1:
                raise InputError(f"'{path.name}' mixes space units {units}; voxflex needs one length unit")
            scale = _unit_scale(units[0], f"'{path.name}'")
        spacing, origin, direction = _frame_from_centre_affine(matrix * scale, centre * scale, path)
        return dict(labels=data, spacing=spacing, origin=origin, direction=direction)
    spacings = header.get("spacings")
    spacing = None
    if spacings is not None:
        spacing = np.asarray(spacings, dtype=float)[:3]
    return dict(labels=data, spacing=spacing)


def _write_nrrd(image, path):
    nrrd = _require("nrrd", "NRRD")

    matrix, centre = _centre_affine(image)
    header = {
        "space": "left-posterior-superior",
        "space directions": matrix.T,  # pynrrd: one row per axis
        "space origin": centre,
        "space units": ["m", "m", "m"],
        "kinds": ["domain", "domain", "domain"],
        "encoding": "gzip",
    }
    with atomic_path(path) as tmp:
        nrrd.write(str(tmp), np.asarray(image.labels), header, index_order="F")


# -- MetaImage (SimpleITK) --------------------------------------------------------------


def _read_itk(path):
    sitk = _require("SimpleITK", "MetaImage")

    img = sitk.ReadImage(str(path))
    n_comp = img.GetNumberOfComponentsPerPixel()
    if n_comp != 1:
        raise InputError(
            f"'{path.name}' has {n_comp} components per voxel; a label image has one: extract the label channel first"
        )
    dim = img.GetDimension()
    arr = sitk.GetArrayFromImage(img)  # (..., z, y, x): reversed axes
    arr = arr.transpose(tuple(range(arr.ndim - 1, -1, -1)))  # (x, y, z, ...)
    if dim < 3:
        raise InputError(f"'{path.name}' is a {dim}-D image; voxflex needs a 3-D label volume")
    arr = _spatial_array(arr, path)
    spacing = np.asarray(img.GetSpacing(), dtype=float)[:3]
    centre = np.asarray(img.GetOrigin(), dtype=float)[:3]
    direction = np.asarray(img.GetDirection(), dtype=float).reshape(dim, dim)[:3, :3]
    spacing, origin, direction = _frame_from_centre_affine(direction * spacing, centre, path)
    return dict(labels=arr, spacing=spacing, origin=origin, direction=direction)


def _write_itk(image, path):
    sitk = _require("SimpleITK", "MetaImage")

    img = sitk.GetImageFromArray(np.ascontiguousarray(image.labels.transpose(2, 1, 0)))
    matrix, centre = _centre_affine(image)
    img.SetSpacing(image.spacing.tolist())
    img.SetOrigin(centre.tolist())
    img.SetDirection(image.direction.ravel().tolist())  # row-major, columns = axes
    if path.name.lower().endswith(".mhd"):
        # header + separate data file: write both under their final names in a
        # private folder, then move the data file and (atomically) the header.
        folder = path.parent if str(path.parent) else Path(".")
        with tempfile.TemporaryDirectory(prefix=".voxflex-", dir=folder) as work:
            header = Path(work) / path.name
            sitk.WriteImage(img, str(header), True)
            for item in Path(work).iterdir():
                if item != header:
                    os.replace(item, folder / item.name)
            with atomic_path(path) as tmp:
                os.replace(header, tmp)
    else:
        with atomic_path(path) as tmp:
            sitk.WriteImage(img, str(tmp), True)


# -- TIFF ---------------------------------------------------------------------------


def _read_tiff(path):
    tifffile = _require("tifffile", "TIFF")

    with tifffile.TiffFile(str(path)) as tif:
        if not tif.series:
            raise InputError(f"'{path.name}' holds no image; check the file")
        series = tif.series[0]
        axes = series.axes.upper()
        data = series.asarray()
        ours = tif.shaped_metadata[0].get("voxflex") if tif.is_shaped and tif.shaped_metadata else None
        imagej = tif.imagej_metadata if tif.is_imagej else None
        tags = tif.pages[0].tags
        xres = tags["XResolution"].value if "XResolution" in tags else None
        yres = tags["YResolution"].value if "YResolution" in tags else None
    # keep X, Y and one stack axis (Z, or generic pages I/Q); singleton axes go
    kept, z_axis = {}, None
    for ax, (letter, n) in enumerate(zip(axes, data.shape)):
        if letter in "XY":
            kept[letter] = ax
        elif n == 1:
            continue
        elif letter in "ZIQ" and z_axis is None:
            z_axis = ax
        else:
            raise InputError(
                f"'{path.name}' has {n} components along TIFF axis '{letter}' (axes {axes}, shape {data.shape}); "
                "a label image has one value per voxel: extract the label channel first"
            )
    if "X" not in kept or "Y" not in kept:
        raise InputError(f"'{path.name}' has no X/Y image axes (axes {axes}); it is not an image stack")
    order = [kept["X"], kept["Y"]] + ([z_axis] if z_axis is not None else [])
    drop = tuple(ax for ax in range(data.ndim) if ax not in order)
    labels = np.transpose(data, order + list(drop)).reshape([data.shape[ax] for ax in order])
    if labels.ndim == 2:
        labels = labels[:, :, None]
    if ours is not None:
        try:
            spacing = np.asarray(ours["spacing"], dtype=float)
            origin = np.asarray(ours["origin"], dtype=float)
        except (KeyError, TypeError, ValueError):
            raise InputError(f"'{path.name}' has damaged voxflex metadata; re-save the image") from None
        return dict(labels=labels, spacing=spacing, origin=origin)
    imagej_unit = str((imagej or {}).get("unit", "")).strip().lower()
    if imagej and "spacing" in imagej and xres and yres and imagej_unit not in ("", "pixel", "pixels"):
        scale = _unit_scale(imagej["unit"], f"'{path.name}' (ImageJ unit)")
        sx, sy = xres[1] / xres[0], yres[1] / yres[0]  # resolution = pixels per unit
        spacing = scale * np.array([sx, sy, float(imagej["spacing"])])
        return dict(labels=labels, spacing=spacing)
    return dict(labels=labels, spacing=None)


def _write_tiff(image, path):
    tifffile = _require("tifffile", "TIFF")

    meta = {
        "axes": "ZYX",
        "voxflex": {
            "spacing": image.spacing.tolist(),
            "origin": image.origin.tolist(),
            "units": "m",
            "note": "pages are z; origin is the corner of voxel (0,0,0)",
        },
    }
    sx, sy = image.spacing[:2] * 100.0  # centimetres, for other viewers' pixel size
    with atomic_path(path) as tmp:
        tifffile.imwrite(
            str(tmp),
            np.ascontiguousarray(image.labels.transpose(2, 1, 0)),
            photometric="minisblack",
            metadata=meta,
            resolution=(1.0 / sx, 1.0 / sy),
            resolutionunit="CENTIMETER",
            compression="zlib",
        )


# -- HDF5 ---------------------------------------------------------------------------------


def _read_h5(path):
    import h5py

    with h5py.File(str(path), "r") as f:
        group = f.get("image")
        if not isinstance(group, h5py.Group) or not isinstance(group.get("labels"), h5py.Dataset):
            kind = "result file" if "time" in f else "HDF5 file"
            raise InputError(
                f"{kind} '{path.name}' has no /image/labels dataset; it is not a voxflex image or result file"
            )
        dataset = group["labels"]
        out = dict(labels=dataset[()], spacing=None)
        for key in ("spacing", "origin", "direction"):
            # geometry attrs on the group (this module's layout) or on the dataset (voxflex.result's)
            where = group.attrs if key in group.attrs else dataset.attrs
            if key in where:
                out[key] = np.asarray(where[key], dtype=float)
        if isinstance(group.get("occupancy"), h5py.Dataset):
            out["occupancy"] = group["occupancy"][()]
    return out


def _write_h5(image, path):
    import h5py

    from .._version import __version__

    with atomic_path(path) as tmp, h5py.File(str(tmp), "w") as f:
        f.attrs["voxflex_version"] = __version__
        group = f.create_group("image")
        dataset = group.create_dataset("labels", data=image.labels, compression="gzip", shuffle=True)
        for attrs in (group.attrs, dataset.attrs):  # both places, as voxflex.result writes them
            attrs["spacing"] = image.spacing
            attrs["origin"] = image.origin
            attrs["direction"] = image.direction
        group.attrs["units"] = "m"
        if image.occupancy is not None:
            group.create_dataset("occupancy", data=image.occupancy, compression="gzip", shuffle=True)


# -- VTK ImageData ----------------------------------------------------------------------------


def _read_vti(path):
    import logging
    import warnings

    import pyvista as pv

    # VTK reports a corrupt file through its logger, Python logging and a
    # warning, then returns an empty grid: silence the chatter, raise instead.
    previous = logging.root.manager.disable
    logging.disable(logging.CRITICAL)
    try:
        with pv.vtk_verbosity("off"), warnings.catch_warnings():
            warnings.simplefilter("error")
            grid = pv.read(str(path))
    except Exception:
        raise InputError(
            f"cannot read '{path.name}' as VTK ImageData: VTK could not parse it (corrupt, truncated or not VTK XML); "
            "check that the file is a complete .vti image"
        ) from None
    finally:
        logging.disable(previous)
    if not isinstance(grid, pv.ImageData):
        raise InputError(f"'{path.name}' holds a {type(grid).__name__}, not VTK ImageData; it is not a label image")
    dims = np.asarray(grid.dimensions, dtype=int)
    spacing = np.asarray(grid.spacing, dtype=float)
    direction = np.asarray(grid.direction_matrix, dtype=float)
    corner = np.asarray(grid.origin, dtype=float)

    def pick(data, kind):
        names = list(data.keys())
        name = "labels" if "labels" in names else (names[0] if len(names) == 1 else None)
        if name is None:
            return None
        arr = np.asarray(data[name])
        if arr.ndim > 1 and arr.shape[1] != 1:
            raise InputError(
                f"'{path.name}' {kind} array '{name}' has {arr.shape[1]} components per voxel; "
                "a label image has one: extract the label channel first"
            )
        return arr.reshape(-1)

    labels = pick(grid.cell_data, "cell")
    if labels is not None and np.all(dims > 1):
        shape = dims - 1  # voxels are cells: the origin is the corner of voxel 0
        out = dict(labels=labels.reshape(shape, order="F"), spacing=spacing, origin=corner, direction=direction)
        if "occupancy" in grid.cell_data.keys():
            out["occupancy"] = np.asarray(grid.cell_data["occupancy"]).reshape(shape, order="F")
        return out
    labels = pick(grid.point_data, "point")
    if labels is None:
        raise InputError(f"'{path.name}' has no 'labels' cell or point array; it is not a label image")
    # voxels centred on the points: the corner is half a voxel before the first point
    spacing_, origin, direction = _frame_from_centre_affine(direction * spacing, corner, path)
    return dict(labels=labels.reshape(dims, order="F"), spacing=spacing_, origin=origin, direction=direction)


def _write_vti(image, path):
    import pyvista as pv

    grid = pv.ImageData(
        dimensions=np.array(image.shape) + 1,
        spacing=image.spacing,
        origin=image.origin,
        direction_matrix=image.direction,
    )
    grid.cell_data["labels"] = image.labels.ravel(order="F")
    if image.occupancy is not None:
        grid.cell_data["occupancy"] = image.occupancy.ravel(order="F")
    grid.cell_data.active_scalars_name = "labels"
    with atomic_path(path) as tmp:
        grid.save(str(tmp), binary=True)


_READERS = {
    "NumPy": _read_npy,
    "NumPy archive": _read_npz,
    "NIfTI": _read_nifti,
    "NRRD": _read_nrrd,
    "MetaImage": _read_itk,
    "TIFF": _read_tiff,
    "HDF5": _read_h5,
    "VTK ImageData": _read_vti,
}


_WRITERS = {
    "NumPy": _write_npy,
    "NumPy archive": _write_npz,
    "NIfTI": _write_nifti,
    "NRRD": _write_nrrd,
    "MetaImage": _write_itk,
    "TIFF": _write_tiff,
    "HDF5": _write_h5,
    "VTK ImageData": _write_vti,
}
