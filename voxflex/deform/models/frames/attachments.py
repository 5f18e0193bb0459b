"""What the frame model gives the layers around it: mass and gravity at the voxel centres, mapped points
(probes, contact, cables, the visual surface, load surfaces) and the boundary conditions.

:class:`FrameAttachments` is a part of :class:`~voxflex.deform.models.frames.model.FrameModel` (its mixin): it
reads the model's image, frames, nodes, shape function and caches, and answers the
:class:`~voxflex.deform.models.protocol.Model` protocol's questions that are not the elastic energy.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import scipy.sparse as sp

from ....errors import InputError
from ....image.grid import TrilinearGrid
from ....image.surface import boundary_quads, face_points, triangulate
from ...chain.mappings import PointMapping
from ..protocol import Part, SurfacePoints
from .mass import mass_matrix as frame_mass_matrix
from .mass import point_mass

__all__ = ["FrameAttachments"]


class FrameAttachments:
    """Mass, gravity, mapped points and boundary conditions of a frame model (a mixin of ``FrameModel``)."""

    # -- mass and gravity --------------------------------------------------------
    def _mass_points(self):
        """Mass points: the voxel centres, their volumes (occupancy-weighted) and labels (no shape values)."""
        if self._mass_points_cache is None:
            ijk = np.argwhere(self.image.labels > 0)
            vol = np.full(len(ijk), float(self.image.voxel_volume))
            if self.use_occupancy and self.image.occupancy is not None:
                vol = vol * np.asarray(self.image.occupancy, dtype=float)[ijk[:, 0], ijk[:, 1], ijk[:, 2]]
            label = self.image.labels[ijk[:, 0], ijk[:, 1], ijk[:, 2]].astype(np.int64)
            self._mass_points_cache = (self.image.index_to_world(ijk + 0.5), vol, label)
        return self._mass_points_cache

    def _mass_layer(self):
        """Mass points' volumes, labels and their mapping (shape functions evaluated once, on demand)."""
        if self._mass_map_cache is None:
            pts, vol, label = self._mass_points()
            self._mass_map_cache = (vol, label, PointMapping(self.nodes, self.shape_function(pts)))
        return self._mass_map_cache

    def _point_masses(self, densities) -> np.ndarray:
        if densities is None:
            raise InputError("densities are needed (mass, gravity, dynamics); give a density per material label")
        _, vol, label = self._mass_points()
        dens = {int(k): float(v) for k, v in dict(densities).items()}
        missing = sorted({int(x) for x in np.unique(label)} - set(dens))
        if missing:
            raise InputError(f"label(s) {missing} have no density; give a density per material label")
        table = np.zeros(int(label.max()) + 1)
        for k, v in dens.items():
            if k < len(table):
                table[k] = v
        return table[label] * vol

    def mass_matrix(self, densities: Mapping[int, float], *, lumped: bool = True) -> sp.csr_matrix:
        """Mass matrix (12n, 12n): consistent ``J^T diag(m) J`` or lumped per frame (see the module docstring;
        :func:`.mass.mass_matrix`).  Kept per (densities, lumped) on the model, which every run of a scene
        reuses (reproducing kernels' point mass: 0.22 s of a 10-step run of the bunny at 3 mm with 60 frames,
        1.6 s); a copy is returned."""
        key = (tuple(sorted((repr(k), repr(v)) for k, v in dict(densities).items())), bool(lumped))
        store = self.__dict__.setdefault("_mass_store", {})
        if key not in store:
            store[key] = frame_mass_matrix(self, densities, lumped=lumped)
        return store[key].copy()

    def _point_mass(self, values, masses, chunk: int = 4096) -> sp.csr_matrix:
        """``J^T diag(m) J`` of point masses at the points of ``values`` (:func:`.mass.point_mass`)."""
        return point_mass(self, values, masses, chunk)

    def gravity_force(self, densities: Mapping[int, float], g) -> np.ndarray:
        """Generalised gravity force (n, 12): ``J^T (m g)`` at the mass points."""
        g = np.asarray(g, dtype=float)
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise InputError(f"gravity must be 3 finite numbers (m/s^2), got {np.asarray(g).tolist()}")
        mp = self._point_masses(densities)
        _, _, pmap = self._mass_layer()
        return pmap.vjp(self.rest, mp[:, None] * g[None, :])

    # -- layers ----------------------------------------------------------------
    def point_mapping(self, points) -> PointMapping:
        """Mapping of material points (m, 3) given at rest; InputError outside the material."""
        pts = np.asarray(points, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise InputError(f"points must be an (m, 3) array, got shape {pts.shape}")
        self._check_inside(pts)
        return PointMapping(self.nodes, self.shape_function(pts))

    def _check_inside(self, pts):
        """Points must lie in (the closure of) a material voxel: a point on a face or a corner
        belongs to every voxel touching it."""
        grid = self._grid()
        f = grid.world_to_index(pts)
        tol = max(1e-9, grid.index_roundoff(pts))  # a point on a face far from the origin: its round-off
        labels = self.image.labels
        shape = np.asarray(labels.shape)
        ok = np.zeros(len(pts), dtype=bool)
        lo = np.floor(f + tol).astype(np.int64)
        for d in np.array([[a, b, c] for a in (0, -1) for b in (0, -1) for c in (0, -1)]):
            cell = lo + d
            inside = np.all((cell >= 0) & (cell < shape), axis=1)
            near = np.all((f >= cell - tol) & (f <= cell + 1 + tol), axis=1)
            c = np.clip(cell, 0, shape - 1)
            ok |= inside & near & (labels[c[:, 0], c[:, 1], c[:, 2]] > 0)
        if not np.all(ok):
            bad = int(np.flatnonzero(~ok)[0])
            raise InputError(f"point {pts[bad].tolist()} lies outside the material; give points inside the object")

    def _grid(self) -> TrilinearGrid:
        if self._surface is None:
            self._surface = {"grid": TrilinearGrid.from_image(self.image)}
        return self._surface["grid"]

    def boundary_faces(self):
        """Voxel faces exposed to empty space: corners (F, 4, 3), area (F,), outward normal (F, 3)."""
        grid = self._grid()
        if "quads" not in self._surface:
            self._surface["quads"] = boundary_quads(grid, self.image.labels > 0)
        quads, area, normal = self._surface["quads"]
        return grid.node_positions[quads], area, normal

    def boundary_surface(self):
        """The visual layer: the voxelized boundary (rest vertices, triangles) and its frame mapping."""
        grid = self._grid()
        self.boundary_faces()
        if "surface" not in self._surface:
            vertex_node, faces = triangulate(self._surface["quads"][0])
            V = grid.node_positions[vertex_node]
            self._surface["surface"] = (V, faces, PointMapping(self.nodes, self.shape_function(V)))
        V, faces, pmap = self._surface["surface"]
        return V.copy(), faces, pmap

    def volume_points(self):
        """Material points integrating the volume: the voxel centres and their volumes (m^3)."""
        pts, vol, _ = self._mass_points()
        return pts, vol

    # -- boundary conditions -----------------------------------------------------
    def held_dofs(self, lo, hi, components: str = "xyz") -> np.ndarray:
        """DOFs a fixed box [lo, hi] holds: those of the frames in the box or in a voxel the box
        touches (a thin box around a face holds the frames of the first voxel layer); for component c,
        row c of A and t_c.  Material points without a frame follow the frames."""
        from ....voronoi.placement import voxel_boxes_meet

        lo = np.asarray(lo, dtype=float)
        hi = np.asarray(hi, dtype=float)
        in_box = np.all((self.frames >= lo) & (self.frames <= hi), axis=1)
        f = np.floor(self._grid().world_to_index(self.frames) + 1e-9).astype(np.int64)
        f = np.clip(f, 0, np.asarray(self.image.shape) - 1)
        touched = voxel_boxes_meet(self.image, f, lo, hi)  # the frames' voxels only, not the whole grid's
        frames = np.flatnonzero(in_box | touched)
        local = []
        for c in components:
            i = "xyz".index(c)
            local += [3 * i, 3 * i + 1, 3 * i + 2, 9 + i]
        local = np.array(sorted(local), dtype=np.int64)
        return np.sort((12 * frames[:, None] + local[None, :]).ravel())

    def moved_state(self, transform) -> np.ndarray:
        """State (n, 12) of the body moved by ``[A | t]``: every frame's matrix A, origin A X_a + t."""
        T = np.asarray(transform, dtype=float)
        A, t = T[:, :3], T[:, 3]
        out = np.empty((self.n_nodes, 12))
        out[:, :9] = A.reshape(9)
        out[:, 9:] = self.frames @ A.T + t
        return out

    def rigid_modes(self) -> np.ndarray:
        """(12n, 6): translations (dt = e_k) and rotations about the frames' centroid (dA = [e_k]x, dt = e_k x (X_a - c))."""
        return self.nodes.rigid_modes()

    def parts(self) -> list:
        """Material components as the shape functions couple them (voxels touching by a face, an edge
        or a corner: the connectivity of the geodesic distances), each moved by the frames in it."""
        comps, n = self.image.connected_components(connectivity="vertex")
        f = np.floor(self._grid().world_to_index(self.frames) + 1e-9).astype(np.int64)
        f = np.clip(f, 0, np.asarray(comps.shape) - 1)
        of_frame = comps[f[:, 0], f[:, 1], f[:, 2]] - 1
        return Part.of_components(self.image, comps, [np.flatnonzero(of_frame == c) for c in range(n)])

    def load_surface(self, order: int = 2) -> SurfacePoints:
        """``order`` x ``order`` Gauss points of every voxel face exposed to empty space."""
        corners, area, normal = self.boundary_faces()
        pts, w, face = face_points(corners, area, order)
        return SurfacePoints(pts, w, normal[face], face, corners.mean(axis=1))

    def node_points(self, q) -> np.ndarray:
        """Each frame's origin t (n, 3) at state q."""
        return np.asarray(q, dtype=float).reshape(self.n_nodes, 12)[:, 9:12].copy()

    def point_sample_refusal(self, labels) -> str:
        """Internal variables need point samples with the full volumetric term: refused on stabilised
        mid-point regions (their fluctuation about the region's mean F stays elastic) and on labels whose
        volume ratio is projected.  Elastons are point samples (a sub-rule's Gauss points)."""
        fix = "give the plastic label(s) elastic behaviour, or"
        if self.hourglass == "stiffness" and self.samples.kind == "midpoint":
            return ("plasticity on stabilised mid-point regions would yield at each region's mean F only, the "
                    "fluctuation about it staying elastic (8 frames on the plastic bar: permanent set / bent 0.12 "
                    f"against 0.25 with Gauss-Legendre); {fix} use [elasticity] quadrature = \"elaston\" or "
                    '"gauss-legendre" (or hourglass = "none", the bare one-point rule)')
        reduced = sorted(int(lab) for lab in labels if self.volumetric.get(int(lab), False))
        if reduced:
            return (f"plasticity needs the full volumetric term, but label(s) {reduced} use F-bar; [elasticity] "
                    'volumetric = "full" (or a Poisson ratio below 0.4 under "auto")')
        return ""
