"""The membrane model: the vertices of a triangle mesh as nodes, a plane-stress membrane, a follower pressure.

A :class:`MembraneModel` is a model of the protocol in :mod:`voxflex.deform.models.protocol`
(``node_kind = "membrane"``): its ``n`` nodes are the vertices of a triangle mesh,
3 DOF each (their world positions, m), so the state ``q`` is ``(n, 3)`` and
the rest state the mesh itself.

Elasticity.  Each triangle's 2-D deformation gradient ``F`` (3×2) comes from
the :class:`~voxflex.deform.chain.membrane.TriangleDeformationMapping` (constant J)
and the :class:`~voxflex.deform.chain.membrane.StVKMembrane` gives its energy per
rest area; one point per triangle integrates it exactly (F is constant on a
linear triangle)::

    E_el(x) = sum_t A_t psi(F_t(x)),   g = J^T (A P),   H = J^T blockdiag(A_t dP/dF) J

(J constant, so there is no geometric term of the mapping; the geometric
stiffness of the stress is inside dP/dF).

Pressure.  A pressure p (Pa) pushes every triangle along its current unit
normal ``n_t`` (right-hand rule of its vertex order) with the force
``p A_t n_t`` (``A_t`` the current area), a third to each corner.  That
follower force is conservative when the membrane is clamped along its open
rim or closed: its potential is ``-p V(x)`` with the volume of the cones from
a fixed point ``o`` (the rest centroid) over the triangles,

    V(x) = 1/6 sum_t (a - o) . ((b - o) x (c - o)),     (a, b, c) the corners of t,
    dV/da = 1/6 (b - o) x (c - o)   (cyclic),
    d2V/da db = -[c - o]x / 6,  d2V/db da = +[c - o]x / 6   (cyclic; zero diagonal blocks).

``dV/da`` summed over the triangles around a vertex equals ``sum_t A_t n_t / 3``
exactly when the fan of triangles around it is closed (an interior vertex, or
any vertex of a closed mesh): the terms ``(a - o) x (b - c) / 6`` telescope to
zero.  On an open rim they do not, so a pressure needs every rim vertex held
(:func:`voxflex.build.model` refuses a scene where it is not); then
``p (V(x) - V(X))`` is the work of the pressure (p times the swept volume).
The tests compare the gradient with ``p A_t n_t / 3`` and the Hessian with
finite differences.  In static runs the pressure grows with the load factor
(``p s``), in dynamics it acts in full from t = 0, as the other loads do.

Because the pressure is a potential, the model's energy (what the solvers
minimise and the result file records as ``/energy/elastic``) is the strain
energy minus ``p s (V(x) - V(X))``; :meth:`MembraneModel.strain_energy` and
:meth:`MembraneModel.volume` give the parts.

A flat, unstressed membrane has no stiffness normal to its plane (the
out-of-plane modes are zero-energy to second order), so Newton cannot start a
pressure load from it.  A static step that starts from a flat state with a
non-zero pressure therefore starts from a small bulge instead
(:meth:`MembraneModel.begin_step`): the bubble shape ``phi`` (the graph
Laplacian's response to a uniform load with the open rim at zero) along the
plane's normal, scaled by the minimiser of the potential along it (a scalar
search).

Mass: ``rho h`` per rest area, lumped (a third of each triangle's mass to each
corner) or consistent (``rho h A / 12 (1 + delta_ij)``); gravity ``rho h A g / 3``
per corner.  The visual surface is the mesh itself.  The result file needs a
label image: the model's :attr:`~MembraneModel.image` is the membrane's
footprint, the voxels of size ``voxel_size`` the mesh passes through (label 1).

Geometry: :func:`disk_mesh` and :func:`rectangle_mesh` make flat sheets,
:func:`load_membrane_mesh` reads a surface mesh file (open or closed).

Example
-------
>>> import numpy as np
>>> from voxflex.deform.chain.membrane import StVKMembrane
>>> X, T = disk_mesh(1.0, 0.5)
>>> model = MembraneModel(X, T, StVKMembrane(young=1e6, poisson=0.3, thickness=1e-3), density=1000.0)
>>> model.node_kind, model.rest.shape, len(model.triangles)
('membrane', (19, 3), 24)
>>> float(model.energy(1.1 * X)) > 0, abs(float(model.energy(X + 1.0))) < 1e-12
(True, True)
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import scipy.sparse as sp

from ....errors import InputError
from ....rasterize.membrane_mesh import (
    FLAT_TOL,
    _consistently_oriented,
    _sample_triangles,
    footprint_image,
    open_rim,
)
from ...chain.membrane import StVKMembrane, TriangleDeformationMapping
from ..protocol import OnePass, Part
from .kind import MEMBRANE

__all__ = ["MembraneModel", "VertexMap"]

"""``[nodes] kind`` of the membrane model."""




def _closest_on_triangles(p, a, b, c):
    """Closest points (m, 3) on the triangles (a, b, c) (each (m, 3)) to the point p (3,) and their
    barycentric weights (m, 3)."""
    ab, ac = b - a, c - a
    n = np.cross(ab, ac)
    nn = np.einsum("ij,ij->i", n, n)
    # barycentric coordinates of the projection onto the plane
    w = p - a
    v = np.einsum("ij,ij->i", np.cross(w, ac), n) / nn
    u = np.einsum("ij,ij->i", np.cross(ab, w), n) / nn
    bary = np.stack([1 - v - u, v, u], axis=1)
    inside = np.all(bary >= 0, axis=1)
    best = np.where(inside[:, None], bary, np.nan)
    best_d = np.where(inside, np.abs(np.einsum("ij,ij->i", w, n)) / np.sqrt(nn), np.inf)
    corners = (a, b, c)
    for i, j in ((0, 1), (1, 2), (2, 0)):
        e = corners[j] - corners[i]
        s = np.clip(np.einsum("ij,ij->i", p - corners[i], e) / np.einsum("ij,ij->i", e, e), 0.0, 1.0)
        q = corners[i] + s[:, None] * e
        d = np.linalg.norm(p - q, axis=1)
        better = d < best_d
        cand = np.zeros((len(a), 3))
        cand[:, i] = 1 - s
        cand[:, j] = s
        best = np.where(better[:, None], cand, best)
        best_d = np.where(better, d, best_d)
    return best, best_d


# ----------------------------------------------------------------------------------------------
# point mapping
# ----------------------------------------------------------------------------------------------
class VertexMap:
    """Material points of a membrane as fixed barycentric combinations of its vertices.

    Linear in the free vertices (plus the constant contribution of the clamped
    ones, at rest): J is constant and ``vjp`` exact for any state.

    Parameters
    ----------
    n_nodes : int, the model's nodes (free vertices)
    index : (m, 3) int, the vertices (of the whole mesh) of the triangle each point lies on
    weight : (m, 3) float, its barycentric weights (sum to 1)
    model : MembraneModel, optional
        Whose clamped vertices stay at rest (default: every vertex is a node).
    """

    constant_jacobian = True

    def __init__(self, n_nodes: int, index, weight, *, model=None):
        self.n_nodes = int(n_nodes)
        self.index = np.asarray(index, dtype=np.int64)
        self.weight = np.asarray(weight, dtype=float)
        self.model = model

    def _q(self, q):
        q = np.asarray(q, dtype=float)
        if q.shape == (3 * self.n_nodes,):
            q = q.reshape(self.n_nodes, 3)
        if q.shape != (self.n_nodes, 3):
            raise InputError(f"q must be the ({self.n_nodes}, 3) vertex positions, got shape {q.shape}")
        return q

    def apply(self, q) -> np.ndarray:
        """Positions (m, 3) of the points for the vertex positions q (n, 3)."""
        x = self._q(q) if self.model is None else self.model.positions(q)
        return np.einsum("mk,mki->mi", self.weight, x[self.index])

    def vjp(self, q, f) -> np.ndarray:
        """Vertex forces (n, 3) of point forces f (m, 3)."""
        self._q(q)
        f = np.asarray(f, dtype=float)
        if f.shape != (len(self.index), 3):
            raise InputError(f"f must have shape ({len(self.index)}, 3), got {f.shape}")
        node = self.index.ravel() if self.model is None else self.model._index_of[self.index.ravel()]
        share = (self.weight[:, :, None] * f[:, None, :]).reshape(-1, 3)
        keep = node >= 0  # forces on clamped vertices go to the clamp
        out = np.zeros((self.n_nodes, 3))
        np.add.at(out, node[keep], share[keep])
        return out


# ----------------------------------------------------------------------------------------------
# the model
# ----------------------------------------------------------------------------------------------
def _skew(v):
    """[v]x (m, 3, 3) of vectors v (m, 3)."""
    z = np.zeros(len(v))
    return np.stack([np.stack([z, -v[:, 2], v[:, 1]], 1), np.stack([v[:, 2], z, -v[:, 0]], 1),
                     np.stack([-v[:, 1], v[:, 0], z], 1)], 1)


class MembraneModel(OnePass):
    """A triangle-mesh membrane (see the module docstring): nodes = vertices, state (n, 3) in m.

    Parameters
    ----------
    points : (n, 3) float
        Rest positions of the vertices (m).
    triangles : (m, 3) int
        Vertex indices (non-degenerate at rest; consistently oriented when loaded by a pressure).
    material : StVKMembrane
        The membrane law (its thickness h is the sheet's).
    density : float, optional
        Mass density rho (kg/m^3); the areal density is rho h.  Also taken from
        the ``densities`` mapping (label 1) of :meth:`mass_matrix` and :meth:`gravity_force`.
    pressure : float
        Pressure p (Pa) along the triangles' normals (0: none).
    pressure_ramp : bool
        True: the pressure grows with the load factor given to :meth:`begin_step`
        (static runs); False: it acts in full at every state (dynamics).
    voxel_size : float, optional
        Voxel size (m) of the footprint :attr:`image` (default: the mean edge length).
    label : int
        The label of the membrane's material (1).

    Attributes
    ----------
    mapping : TriangleDeformationMapping
    area : (m,) float, rest areas (m^2)
    fraction : float, the load factor of the pressure (static runs; 1 at construction when not ramped)
    """

    kind = MEMBRANE
    node_kind = MEMBRANE.name
    dofs_per_node = 3
    supported_by_contact = False

    def __init__(self, points, triangles, material, *, density: float | None = None, pressure: float = 0.0,
                 pressure_ramp: bool = True, clamped=None, voxel_size: float | None = None, label: int = 1):
        if not isinstance(material, StVKMembrane):
            raise InputError("a membrane model needs a StVKMembrane material (voxflex.deform.chain.membrane)")
        self.mapping = TriangleDeformationMapping(points, triangles)
        X = np.asarray(points, dtype=float).copy()
        X.setflags(write=False)
        self.points = X
        self.triangles = self.mapping.triangles
        N = len(X)
        clamped = np.zeros(0, dtype=np.int64) if clamped is None else np.unique(np.asarray(clamped, dtype=np.int64))
        if clamped.size and (clamped.min() < 0 or clamped.max() >= N):
            raise InputError(f"clamped vertices must be indices in [0, {N})")
        self.clamped = clamped
        self.free = np.setdiff1d(np.arange(N), clamped)
        if len(self.free) == 0:
            raise InputError("every vertex of the membrane is clamped: nothing to simulate")
        rest = X[self.free].copy()
        rest.setflags(write=False)
        self.rest = rest
        self._free_dofs = (3 * self.free[:, None] + np.arange(3)).ravel()
        self.area = self.mapping.area
        self.material = material
        self.label = int(label)
        self.materials = {self.label: material}
        self.thickness = material.thickness
        if density is not None and not (np.isfinite(density) and density > 0):
            raise InputError(f"density must be > 0 (kg/m^3), got {density!r}")
        self.density = None if density is None else float(density)
        p = float(pressure)
        if not np.isfinite(p):
            raise InputError(f"pressure must be finite (Pa), got {pressure!r}")
        if p != 0.0 and not _consistently_oriented(self.triangles):
            raise InputError("the membrane's triangles are not consistently oriented (two neighbours traverse "
                             "their shared edge the same way), so a pressure has no side; re-orient the mesh")
        self.pressure = p
        self.pressure_ramp = bool(pressure_ramp)
        self.fraction = 0.0 if self.pressure_ramp else 1.0
        self._coef = self.mapping.corner_coefficients  # (m, 3, 2)
        self._origin = X.mean(axis=0)  # the volume's cone apex; rotations turn about it too
        self._V0 = self._volume(X)
        edges = X[self.triangles[:, [1, 2, 0]]] - X[self.triangles]
        self.edge_length = float(np.linalg.norm(edges, axis=2).mean())
        self.voxel_size = float(voxel_size) if voxel_size is not None else self.edge_length
        self.rim = open_rim(self.triangles)
        self._image = None
        self._index_of = -np.ones(N, dtype=np.int64)
        self._index_of[self.free] = np.arange(len(self.free))
        m = len(self.triangles)
        T = self.triangles
        # COO pattern of the 9x9 triangle blocks, rows (t, c, i), columns (t, d, k)
        dof = (3 * T[:, :, None] + np.arange(3)).reshape(m, 9)
        self._rows = np.repeat(dof, 9, axis=1).ravel()
        self._cols = np.tile(dof, (1, 9)).ravel()
        self._lumped_area = np.zeros(len(X))
        np.add.at(self._lumped_area, T.ravel(), np.repeat(self.area / 3.0, 3))
        self._n_all = N

    # -- sizes ---------------------------------------------------------------------------------
    @property
    def n_nodes(self) -> int:
        return len(self.rest)

    @property
    def constant_tangent(self) -> bool:
        """False: the membrane is geometrically non-linear."""
        return False

    @property
    def image(self):
        """The footprint label image (made on first use; see :func:`footprint_image`)."""
        if self._image is None:
            self._image = footprint_image(self.points, self.triangles, self.voxel_size)
        return self._image

    def _check_q(self, q) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.shape == (3 * self.n_nodes,):
            q = q.reshape(self.n_nodes, 3)
        if q.shape != (self.n_nodes, 3):
            raise InputError(f"q must be the ({self.n_nodes}, 3) positions of the free vertices (m), got shape "
                             f"{q.shape}")
        return q

    def positions(self, q) -> np.ndarray:
        """All vertex positions (N, 3): the free ones from q (n, 3), the clamped ones at rest."""
        q = self._check_q(q)
        if not self.clamped.size:
            return q
        x = np.array(self.points)
        x[self.free] = q
        return x

    # -- energy ----------------------------------------------------------------------------------
    def _volume(self, x) -> float:
        T = self.triangles
        a, b, c = (x[T[:, k]] - self._origin for k in range(3))
        return float(np.einsum("ti,ti->", a, np.cross(b, c)) / 6.0)

    def volume(self, q) -> float:
        """``V(x) - V(X)`` (m^3): the volume the membrane swept from rest (clamped or closed membranes)."""
        return self._volume(self.positions(q)) - self._V0

    def current_pressure(self) -> float:
        """The pressure acting now: ``p`` times the load factor (static runs) or ``p`` (Pa)."""
        return self.pressure * self.fraction

    def strain_energy(self, q) -> float:
        """The membrane's strain energy (J) alone."""
        F = self.mapping.apply(self.positions(q))
        return float(self.area @ self.material.energy(F))

    def energy_gradient_hessian(self, q, *, gradient: bool = True, hessian: bool = True):
        """(energy J, gradient (n, 3) N or None, Hessian (3n, 3n) CSR N/m or None): exact, any state."""
        x = self.positions(q)
        F = self.mapping.apply(x)
        E = float(self.area @ self.material.energy(F))
        p = self.current_pressure()
        T = self.triangles
        a, b, c = (x[T[:, k]] - self._origin for k in range(3))
        if p != 0.0:
            E -= p * (float(np.einsum("ti,ti->", a, np.cross(b, c)) / 6.0) - self._V0)
        if not (gradient or hessian):
            return E, None, None
        g = None
        if gradient:
            P = self.material.stress(F) * self.area[:, None, None]
            g = self.mapping.vjp(x, P)
            if p != 0.0:
                dV = np.stack([np.cross(b, c), np.cross(c, a), np.cross(a, b)], axis=1) / 6.0  # (m, 3 corners, 3)
                np.add.at(g, T.ravel(), -p * dV.reshape(-1, 3))
            g = g[self.free]
        if not hessian:
            return E, g, None
        A = self.material.tangent(F) * self.area[:, None, None, None, None]  # (m, 3, 2, 3, 2)
        coef = self._coef
        K = np.einsum("tcJ,tiJkL,tdL->tcidk", coef, A, coef, optimize=True)  # (m, 3, 3, 3, 3)
        if p != 0.0:
            s = -p / 6.0
            corners = (a, b, c)
            for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
                S = _skew(corners[k])  # d2V/dx_i dx_j = -[x_k]x / 6, d2V/dx_j dx_i = +[x_k]x / 6
                K[:, i, :, j, :] -= s * S
                K[:, j, :, i, :] += s * S
        return E, g, self._assemble(K.reshape(len(T), 81))

    def _assemble(self, blocks):
        """The (3n, 3n) CSR matrix of the triangles' 9x9 blocks (m, 81), restricted to the free DOFs."""
        n = 3 * self._n_all
        H = sp.csr_matrix((blocks.ravel(), (self._rows, self._cols)), shape=(n, n))
        H.sum_duplicates()
        if self.clamped.size:
            H = H[self._free_dofs][:, self._free_dofs]
        return H

    # -- mass and gravity ----------------------------------------------------------------------------
    def _areal_density(self, densities) -> float:
        rho = None
        if densities is not None:
            d = dict(densities)
            if self.label not in d:
                raise InputError(f"densities must give label {self.label} (the membrane's), got labels {sorted(d)}")
            rho = float(d[self.label])
        elif self.density is not None:
            rho = self.density
        if rho is None or not (np.isfinite(rho) and rho > 0):
            raise InputError("the membrane needs a density > 0 (kg/m^3) for its mass")
        return rho * self.thickness

    def mass_matrix(self, densities: Mapping[int, float] | None = None, *, lumped: bool = True):
        """Mass matrix (3n, 3n) CSR (kg): ``rho h`` per rest area, lumped or consistent."""
        mu = self._areal_density(densities)
        if lumped:
            return sp.diags(np.repeat(mu * self._lumped_area[self.free], 3)).tocsr()
        m = len(self.triangles)
        local = np.kron((np.ones((3, 3)) + np.eye(3)) / 12.0, np.eye(3))  # (9, 9) per unit mass
        vals = (mu * self.area)[:, None, None] * local[None]
        return self._assemble(vals.reshape(m, 81))

    def gravity_force(self, densities: Mapping[int, float] | None, g) -> np.ndarray:
        """Vertex forces (n, 3) (N) of gravity g (3,) m/s^2: ``rho h A_t g / 3`` per corner (exact for
        the linear triangle)."""
        g = np.asarray(g, dtype=float)
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise InputError(f"gravity must be 3 finite numbers (m/s^2), got {g!r}")
        return self._areal_density(densities) * self._lumped_area[self.free, None] * g[None, :]

    def rigid_modes(self) -> np.ndarray:
        """(3n, 6): the three translations and the rotations about the rest centroid (of the free vertices)."""
        n = self.n_nodes
        r = self.rest - self._origin
        B = np.zeros((n, 3, 6))
        for k in range(3):
            B[:, k, k] = 1.0
            B[:, :, 3 + k] = np.cross(np.eye(3)[k], r)
        return B.reshape(3 * n, 6)

    # -- layers ------------------------------------------------------------------------------------------
    def point_mapping(self, points) -> VertexMap:
        """Mapping of material points (k, 3) given at rest: each point's nearest point on the mesh.

        Raises
        ------
        InputError
            A point farther than half the thickness (plus 1e-9 of the mesh size) from the membrane.
        """
        P = np.asarray(points, dtype=float)
        if P.ndim != 2 or P.shape[1] != 3 or not np.all(np.isfinite(P)):
            raise InputError(f"points must be a finite (k, 3) array (m), got shape {P.shape}")
        X, T = self.points, self.triangles
        a, b, c = X[T[:, 0]], X[T[:, 1]], X[T[:, 2]]
        size = float(np.max(np.ptp(X, axis=0)))
        tol = 0.5 * self.thickness + 1e-9 * size
        index = np.zeros((len(P), 3), dtype=np.int64)
        weight = np.zeros((len(P), 3))
        for i, p in enumerate(P):
            bary, dist = _closest_on_triangles(p, a, b, c)
            t = int(np.argmin(dist))
            if dist[t] > tol:
                raise InputError(f"point {p.tolist()} is {dist[t]:.3g} m from the membrane (more than half its "
                                 f"thickness, {0.5 * self.thickness:.3g} m); give a point on the sheet")
            index[i], weight[i] = T[t], bary[t]
        return VertexMap(self.n_nodes, index, weight, model=self)

    def boundary_surface(self):
        """The visual layer: the mesh itself (rest vertices (n, 3), triangles (m, 3), identity mapping)."""
        N = self._n_all
        ident = VertexMap(self.n_nodes, np.repeat(np.arange(N)[:, None], 3, axis=1), np.tile([1.0, 0.0, 0.0], (N, 1)),
                          model=self)
        return np.array(self.points), self.triangles.copy(), ident

    def load_surface(self, order: int = 2):
        """Refused: a membrane has no voxel faces (traction loads need them)."""
        raise InputError('a membrane has no voxel faces for traction loads; push it with [[load]] kind = "pressure" '
                         'or kind = "force" on a region')

    def node_points(self, q):
        """None: the vertices are the surface a render draws."""
        return None

    def volume_points(self):
        """The vertices with their share of the sheet's volume (lumped area times thickness, m^3)."""
        return np.array(self.points), self._lumped_area * self.thickness

    def sample_fields(self, q) -> dict:
        """Per triangle: ``F`` (m, 3, 3) the map from the rest basis (e1, e2, rest normal) to the world
        with the current unit normal as third column (det F = area ratio; thickness change not
        modelled), its ``volume`` (A h), ``label``, ``cell`` (the triangle), ``triangle_cell``."""
        F2 = self.mapping.apply(self.positions(q))
        nrm = np.cross(F2[:, :, 0], F2[:, :, 1])
        ln = np.linalg.norm(nrm, axis=1)
        unit = np.where(ln[:, None] > 0, nrm / np.where(ln > 0, ln, 1.0)[:, None], 0.0)
        F = np.concatenate([F2, unit[:, :, None]], axis=2)
        basis = self.mapping.basis
        N = np.cross(basis[:, :, 0], basis[:, :, 1])
        R = np.concatenate([basis, N[:, :, None]], axis=2)  # rest basis -> world
        m = len(self.triangles)
        return {"F": F @ R.transpose(0, 2, 1), "volume": self.area * self.thickness,
                "label": np.full(m, self.label), "cell": np.arange(m), "n_cells": m, "cell_kind": "samples",
                "materials": dict(self.materials), "triangle_cell": np.arange(m)}

    def parts(self) -> list:
        """The connected parts of the mesh (triangles sharing vertices) that need a support: those the
        clamp does not hold (fewer than 3 non-collinear clamped vertices), each moved by its free vertices."""
        from scipy.sparse.csgraph import connected_components

        n, T = self._n_all, self.triangles
        e = np.concatenate([T[:, [0, 1]], T[:, [1, 2]]])
        G = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
        k, lab = connected_components(G, directed=False)
        used = np.zeros(n, dtype=bool)
        used[T.ravel()] = True
        parts = [c for c in np.unique(lab[used]) if not self._clamped_rigidly(np.intersect1d(
            np.flatnonzero(lab == c), self.clamped))]
        remap = -np.ones(k, dtype=np.int64)
        remap[parts] = np.arange(len(parts))
        image = self.image
        comps = np.zeros(image.shape, dtype=np.int64)
        pts, tri = _sample_triangles(self.points, T, self.voxel_size, which=True)
        ijk = np.clip(np.floor(image.world_to_index(pts)).astype(np.int64), 0, np.asarray(image.shape) - 1)
        sel = remap[lab[T[tri, 0]]] >= 0
        comps[ijk[sel, 0], ijk[sel, 1], ijk[sel, 2]] = remap[lab[T[tri[sel], 0]]] + 1
        nodes_of = [self._index_of[np.flatnonzero((lab == c) & used)] for c in parts]
        return Part.of_components(image, comps, [nd[nd >= 0] for nd in nodes_of], cell="voxels of the footprint")

    def _clamped_rigidly(self, vertices) -> bool:
        """Whether clamped vertices hold a part against every rigid motion (3 of them not on one line)."""
        if len(vertices) < 3:
            return False
        P = self.points[vertices] - self.points[vertices].mean(axis=0)
        sv = np.linalg.svd(P, compute_uv=False)
        return bool(sv[1] > 1e-9 * max(sv[0], 1e-300))

    # -- boundary conditions -------------------------------------------------------------------------
    def held_dofs(self, lo, hi, components: str = "xyz") -> np.ndarray:
        """Flat DOFs of the free vertices whose rest position lies in [lo, hi], for the given components."""
        lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
        inside = np.flatnonzero(np.all((self.rest >= lo) & (self.rest <= hi), axis=1))
        comps = np.array(["xyz".index(c) for c in "xyz" if c in str(components)], dtype=np.int64)
        return np.sort((3 * inside[:, None] + comps[None, :]).ravel())

    def moved_state(self, transform) -> np.ndarray:
        """The free vertices (n, 3) moved by the affine map ``[A | t]`` (3, 4)."""
        T = np.asarray(transform, dtype=float)
        if T.shape != (3, 4) or not np.all(np.isfinite(T)):
            raise InputError(f"a transform must be a finite 3x4 matrix [A | t], got shape {T.shape}")
        return self.rest @ T[:, :3].T + T[:, 3]

    # -- steps -----------------------------------------------------------------------------------------
    def begin_step(self, fraction: float, q_prev, q_start):
        """Set the pressure's load factor (static runs); start a pressurised flat membrane from a bulge.

        With ``pressure_ramp`` the pressure of the step is ``p * fraction``.  When
        the step's start is flat (every triangle normal parallel, see :data:`FLAT_TOL`)
        and that pressure is not zero, the start is lifted along the plane's normal
        by ``alpha phi`` (``phi`` the bubble shape, zero on the open rim; ``alpha``
        the minimiser of the potential along it), since a flat unstressed membrane
        has no stiffness against the pressure.  Returns ``q_start`` itself otherwise.
        """
        f = float(fraction)
        if not np.isfinite(f):
            raise InputError(f"load factor must be finite, got {fraction!r}")
        if self.pressure_ramp:
            self.fraction = f
        if self.current_pressure() == 0.0 or not self.pressure_ramp:
            return q_start
        x = self._check_q(q_start)
        normal = self._flat_normal(self.positions(x))
        if normal is None:
            return q_start
        phi = self._bubble()
        if phi is None:
            return q_start
        d = np.sign(self.current_pressure()) * phi[self.free, None] * normal[None, :]
        alpha = self._line_minimum(x, d)
        if alpha <= 0.0:
            return q_start
        return (x + alpha * d).reshape(np.shape(q_start))

    def _flat_normal(self, x):
        """The common unit normal of the triangles at x when they are all parallel, else None."""
        T = self.triangles
        n = np.cross(x[T[:, 1]] - x[T[:, 0]], x[T[:, 2]] - x[T[:, 0]])
        ln = np.linalg.norm(n, axis=1)
        if np.any(ln == 0):
            return None
        n = n / ln[:, None]
        if np.abs(np.cross(n, n[0])).max() > FLAT_TOL:
            return None
        return n[0]

    def _bubble(self):
        """phi (N,): the graph Laplacian's response to a unit load, zero on the open rim and the clamped
        vertices, max 1; None without either."""
        held = np.union1d(self.rim, self.clamped)
        if len(held) == 0:
            return None
        n, T = self._n_all, self.triangles
        e = np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]])
        W = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
        W = ((W + W.T) > 0).astype(float)
        L = sp.diags(np.asarray(W.sum(axis=1)).ravel()) - W
        free = np.setdiff1d(np.arange(n), held)
        phi = np.zeros(n)
        if len(free) == 0:
            return None
        import scipy.sparse.linalg as spla

        phi[free] = spla.spsolve(L[free][:, free].tocsc(), self._lumped_area[free] / self._lumped_area.mean())
        top = np.abs(phi).max()
        return phi / top if top > 0 else None

    def _line_minimum(self, x, d) -> float:
        """The alpha >= 0 minimising the energy along x + alpha d (bracketed, then Brent)."""
        from scipy.optimize import minimize_scalar

        size = float(np.max(np.ptp(self.points, axis=0)))

        def f(a):
            return self.energy(x + a * d)

        a0, f0 = 0.0, f(0.0)
        a1 = 1e-4 * size
        f1 = f(a1)
        if not f1 < f0:
            return 0.0
        for _ in range(60):
            a2 = 2.0 * a1
            f2 = f(a2)
            if f2 > f1:
                res = minimize_scalar(f, bracket=(a0, a1, a2), method="brent", options={"xtol": 1e-6})
                return float(res.x) if res.fun <= f1 else a1
            a0, a1, f1 = a1, a2, f2
        return a1

    def advice(self) -> str:
        if self.pressure != 0.0:
            return "an inflated membrane stiffens as it bulges: use more load steps for a large pressure"
        return "a membrane without tension has no stiffness normal to its plane"

    def describe(self) -> dict:
        return {"node_kind": self.node_kind, "count": int(self.n_nodes), "dofs": int(3 * self.n_nodes),
                "vertices": int(self._n_all), "clamped": int(self.clamped.size),
                "triangles": int(len(self.triangles)), "thickness": float(self.thickness),
                "pressure": float(self.pressure)}
