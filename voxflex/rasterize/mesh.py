"""Surface meshes: loading, validation, orientation.

A surface mesh is held as a :class:`SurfaceMesh` (vertices (V, 3) float64,
faces (F, 3) int64 triangles).  Files are read with pyvista's readers
(.stl .obj .ply .vtk .vtp), any polygonal cells are triangulated and
degenerate triangles (a repeated vertex index) are dropped.  The mesh need not
be watertight: the inside test is the generalized winding number.

Binary STL files (the bundled default scene's mesh among them) are read by
:func:`_read_binary_stl` with numpy alone, giving the same vertices and faces
as VTK's reader (identical coordinates merged, in order of first appearance),
so that a run on an STL mesh does not pay for importing pyvista and VTK.
"""

from __future__ import annotations

import contextlib
import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError

MESH_EXTENSIONS = (".stl", ".obj", ".ply", ".vtk", ".vtp")


@dataclass(frozen=True, eq=False)
class SurfaceMesh:
    """A triangle surface, validated on construction.

    Parameters
    ----------
    vertices : (V, 3) float, metres
        Finite coordinates.
    faces : (F, 3) int
        Vertex indices of each triangle (F >= 1); triangles with a repeated
        index are dropped.
    name : str
        Where the mesh came from (for messages).
    """

    vertices: np.ndarray
    faces: np.ndarray
    name: str = "mesh"

    def __post_init__(self):
        name = self.name
        try:
            vertices = np.asarray(self.vertices, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(f"{name}: vertices must be numbers of shape (V, 3)") from None
        if vertices.ndim != 2 or vertices.shape[1] != 3:
            raise InputError(f"{name}: vertices must have shape (V, 3), got {vertices.shape}")
        faces = np.asarray(self.faces)
        if faces.ndim != 2 or faces.shape[1] != 3 or faces.shape[0] == 0 and faces.size:
            raise InputError(
                f"{name}: faces must be triangles of shape (F, 3), got {faces.shape}; triangulate the mesh first"
            )
        if faces.size and not np.issubdtype(faces.dtype, np.integer):
            if not np.all(np.isfinite(faces)) or np.any(faces != np.round(faces)):
                raise InputError(f"{name}: faces must hold integer vertex indices")
        faces = faces.astype(np.int64)
        if len(faces) == 0 or len(vertices) == 0:
            raise InputError(f"{name}: the mesh is empty (no triangles); give a closed surface mesh")
        if faces.min() < 0 or faces.max() >= len(vertices):
            raise InputError(
                f"{name}: faces refer to vertex {int(faces.max()) if faces.max() >= len(vertices) else int(faces.min())}"
                f" but the mesh has {len(vertices)} vertices; fix the face indices"
            )
        used = vertices[np.unique(faces)]
        if not np.all(np.isfinite(used)):
            raise InputError(f"{name}: vertex coordinates contain NaN or inf; repair or re-export the mesh")
        keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
        faces = np.ascontiguousarray(faces[keep])
        if len(faces) == 0:
            raise InputError(f"{name}: every triangle is degenerate (repeated vertices); the mesh encloses nothing")
        lo, hi = self._span(vertices, faces)
        if np.any(hi - lo <= 0):
            raise InputError(f"{name}: the mesh is flat (zero extent along an axis), so it encloses no volume to fill "
                             'with voxels; a flat sheet is a membrane: [nodes] kind = "membrane" with a [membrane] table')
        for arr in (vertices, faces):
            arr.setflags(write=False)
        object.__setattr__(self, "vertices", vertices)
        object.__setattr__(self, "faces", faces)

    @staticmethod
    def _span(vertices, faces):
        used = vertices[faces.reshape(-1)]
        return used.min(axis=0), used.max(axis=0)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper corners (3,), (3,) of the used vertices' bounding box."""
        return self._span(self.vertices, self.faces)

    @property
    def signed_volume(self) -> float:
        """Enclosed volume by the divergence theorem (m^3); negative for an inward-oriented surface.

        Exact for a closed surface; only indicative for an open one.
        """
        tri = self.vertices[self.faces]
        return float(np.einsum("ti,ti->t", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0)

    def oriented(self) -> "SurfaceMesh":
        """The mesh with its faces flipped if its signed volume is negative (outward orientation)."""
        if self.signed_volume >= 0:
            return self
        return SurfaceMesh(self.vertices, self.faces[:, ::-1], name=self.name)


def load_mesh(path) -> SurfaceMesh:
    """Read a surface mesh file (.stl .obj .ply .vtk .vtp) into a triangulated :class:`SurfaceMesh`.

    Raises
    ------
    InputError
        Missing or unreadable file, unknown extension, a file with no surface
        triangles, NaN/inf coordinates.
    """
    path = Path(path)
    if path.is_dir():  # named as a folder, not as a bad extension
        from ..errors import missing_file

        raise missing_file(path, "mesh file")
    ext = path.suffix.lower()
    if ext not in MESH_EXTENSIONS:
        raise InputError(
            f"'{path}' is not a surface mesh file; use one of {' '.join(MESH_EXTENSIONS)} "
            "or a primitive spec (box:LX,LY,LZ, cylinder:R,L, sphere:R)"
        )
    if not path.is_file():
        raise InputError(f"mesh file '{path}' not found; check the path")
    if not os.access(path, os.R_OK):
        raise InputError(f"mesh file '{path}' is not readable; check its permissions")
    if path.stat().st_size == 0:
        raise InputError(f"mesh file '{path}' is empty (0 bytes); re-export the mesh")
    if ext == ".stl":
        arrays = _read_binary_stl(path)
        if arrays is not None:
            return SurfaceMesh(arrays[0], arrays[1], name=str(path))
    import pyvista as pv

    with _quiet_vtk() as report:
        try:
            data = pv.read(str(path))
        except Exception as exc:  # the readers raise many types (OSError, ValueError, vtk errors)
            report.messages.append(str(exc) or type(exc).__name__)
            report.failed = True
    if report.failed:
        reason = _first_reason(report.messages)
        raise InputError(
            f"could not read '{path}' as a {ext} mesh ({reason}); check that it is a valid {ext} file"
        ) from None
    if isinstance(data, pv.MultiBlock):
        data = data.combine()
    if not isinstance(data, pv.PolyData):
        try:
            data = data.extract_surface()
        except Exception:
            raise InputError(f"'{path}' holds no surface; give a surface mesh (triangles or polygons)") from None
    if data.n_points == 0 or data.n_cells == 0:
        raise InputError(f"'{path}' contains no surface (0 points or cells); check that it is a valid {ext} mesh")
    if data.n_faces == 0:
        raise InputError(f"'{path}' contains no polygons (only points or lines); give a closed surface mesh")
    try:
        tri = data.triangulate()
    except Exception:
        raise InputError(f"the faces of '{path}' could not be triangulated; re-export them as triangles") from None
    if not tri.is_all_triangles:
        tri = tri.extract_cells_by_type(5).extract_surface() if hasattr(tri, "extract_cells_by_type") else tri
    faces = _triangle_faces(tri, path)
    return SurfaceMesh(np.asarray(tri.points, dtype=np.float64), faces, name=str(path))


_STL_TRIANGLE = np.dtype([("normal", "<f4", (3,)), ("vertices", "<f4", (3, 3)), ("attribute", "<u2")])


def _read_binary_stl(path: Path):
    """Vertices (V, 3) float64 and faces (F, 3) int64 of a well-formed binary STL file, or None.

    The result is what VTK's STL reader gives for the same file: the float32
    corners with identical coordinates merged (``-0.0`` equal to ``0.0``),
    numbered in order of first appearance, one face per triangle in file
    order (:class:`SurfaceMesh` then drops the degenerate ones).  Anything
    else -- an ASCII file (or a binary one whose header starts with
    ``solid``), a size that disagrees with the triangle count, no triangle,
    a non-finite coordinate -- returns None, and the caller reads the file
    with pyvista (whose messages report what is wrong with it).
    """
    with open(path, "rb") as fh:
        header = fh.read(84)
        if len(header) < 84 or header[:5].lower() == b"solid":
            return None
        count = int(np.frombuffer(header, dtype="<u4", count=1, offset=80)[0])
        if count == 0 or path.stat().st_size != 84 + _STL_TRIANGLE.itemsize * count:
            return None
        corners = np.fromfile(fh, dtype=_STL_TRIANGLE, count=count)["vertices"].reshape(-1, 3)
    if len(corners) != 3 * count or not np.all(np.isfinite(corners)):
        return None
    # merge bitwise-equal corners; adding +0.0 turns -0.0 into 0.0, which compare equal in VTK
    keys = np.ascontiguousarray(corners + np.float32(0.0)).view(np.dtype((np.void, 12))).ravel()
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    order = np.argsort(first)  # unique corners in order of first appearance
    number = np.empty_like(order)
    number[order] = np.arange(len(order))
    faces = number[inverse.reshape(-1)].reshape(-1, 3).astype(np.int64)
    return corners[first[order]].astype(np.float64), faces


# messages VTK prints around the real one: pipeline bookkeeping, not a reason
_VTK_NOISE = ("Algorithm ", "No update piece number", "'NewDataObject' cannot create", "The VTK reader ",
              "File reader failed")  # fmt: skip


def _first_reason(messages) -> str:
    """The first informative line of what VTK said, without object addresses (one line, <= 160 chars)."""
    import re

    lines = []
    for message in messages:
        for raw in str(message).splitlines():
            line = raw.strip().strip('"')
            # skip VTK's location headers and the indented dumps of pipeline information
            if not line or raw[:1].isspace() or line.startswith(("ERROR: In ", "Warning: In ")):
                continue
            line = re.sub(r"\s*\(0x[0-9a-fA-F]+\)", "", line)
            lines.append(re.sub(r"^vtk\w+: ", "", line))
    useful = [line for line in lines if not line.startswith(_VTK_NOISE)]
    text = (useful or lines or ["the reader produced no data"])[0]
    return text if len(text) <= 160 else text[:157] + "..."


class _Recorder(logging.Handler):
    """A logging handler that keeps the messages (and whether one was an error) instead of printing them."""

    def __init__(self):
        super().__init__(logging.WARNING)
        self.messages: list[str] = []
        self.error = False

    def emit(self, record):
        self.messages.append(record.getMessage())
        self.error |= record.levelno >= logging.ERROR


class _VtkReport:
    """What VTK said while a reader ran: ``messages`` (its own words first) and whether it ``failed``."""

    def __init__(self):
        self.messages: list[str] = []
        self.failed = False


@contextlib.contextmanager
def _quiet_vtk():
    """Silence VTK while a reader runs; yield a :class:`_VtkReport` filled in after the block.

    VTK reports a reader's failure four ways: its output window, its logger
    (coloured lines on stderr) and, through pyvista, Python logging and a
    warning.  All are captured here and restored afterwards, so a broken file
    gives voxflex's one-line error and nothing else.  The report's messages
    are the output window's text first (VTK's own words), then the logged
    messages, then the warnings; it has ``failed`` when VTK reported an error
    (warnings alone do not fail a read).
    """
    import warnings

    from vtkmodules.vtkCommonCore import (
        vtkLogger,
        vtkOutputWindow,
        vtkStringOutputWindow,
    )

    report = _VtkReport()
    cutoff = vtkLogger.GetCurrentVerbosityCutoff()  # no getter for stderr alone; equal without file sinks
    vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_OFF)
    window = vtkOutputWindow.GetInstance()
    sink = vtkStringOutputWindow()
    vtkOutputWindow.SetInstance(sink)
    root = logging.getLogger()
    handler = _Recorder()
    root.addHandler(handler)  # also keeps logging.error from installing a stderr handler
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            yield report
    finally:
        root.removeHandler(handler)
        vtkOutputWindow.SetInstance(window)
        vtkLogger.SetStderrVerbosity(cutoff)
    text = sink.GetOutput()
    warned = [str(w.message) for w in caught]
    found = [text, *handler.messages, *warned, *report.messages]
    report.messages = [m for m in found if m and m.strip()]
    report.failed |= handler.error or "ERROR: In " in text or any("raised an error" in w for w in warned)


def _triangle_faces(poly, path) -> np.ndarray:
    flat = np.asarray(poly.faces)
    if flat.size == 0:
        raise InputError(f"'{path}' contains no triangles after triangulation; give a closed surface mesh")
    if flat.size % 4 == 0 and np.all(flat.reshape(-1, 4)[:, 0] == 3):
        return flat.reshape(-1, 4)[:, 1:].astype(np.int64)
    raise InputError(f"the faces of '{path}' could not be triangulated; re-export them as triangles")


def as_mesh(source, name: str = "mesh") -> SurfaceMesh:
    """A :class:`SurfaceMesh` from a ``(vertices, faces)`` pair, a pyvista PolyData or a path."""
    if isinstance(source, SurfaceMesh):
        return source
    if isinstance(source, (str, os.PathLike)):
        return load_mesh(source)
    if isinstance(source, tuple) and len(source) == 2:
        return SurfaceMesh(source[0], source[1], name=name)
    if hasattr(source, "triangulate") and hasattr(source, "faces"):
        tri = source.triangulate()
        return SurfaceMesh(np.asarray(tri.points), _triangle_faces(tri, name), name=name)
    raise InputError(f"cannot use {type(source).__name__} as a mesh; give a file path or a (vertices, faces) pair")
