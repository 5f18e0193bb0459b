"""The model protocol: what solvers, loads, boundary conditions, results and renders may ask of a model.

Every simulated model — the full-resolution voxel model
(:class:`~voxflex.deform.models.voxel.model.VoxelModel`) and the reduced frame model
(:class:`~voxflex.deform.models.frames.model.FrameModel`) — is a set of ``n`` nodes
with ``d`` numbers each (the state ``q``, shape ``(n, d)``: ``d = 3`` for
points, 12 for affine frames), an elastic energy ``E(q)`` and mapped layers of
material points.  Nothing outside a model knows how its nodes relate to the
voxels: loads act on the material and reach the nodes through the transposed
Jacobian of a point mapping, fixed regions ask the model which DOFs they hold.

The flat DOF vector is ``q.ravel()`` (node-major), so DOF ``d * node + j``.

Point mappings (:class:`PointMap`) are linear in ``q`` for both node kinds
(trilinear points, affine frames); their ``vjp`` is exact for any state.

Example
-------
>>> import numpy as np
>>> from voxflex.image.label_image import LabelImage
>>> from voxflex.deform.materials.constitutive import material
>>> from voxflex.deform.models.voxel.model import VoxelModel
>>> model = VoxelModel.from_image(LabelImage(np.ones((2, 1, 1))), {1: material("hooke", young=1.0, poisson=0.3)})
>>> isinstance(model, Model), model.node_kind, model.rest.shape
(True, 'voxel', (12, 3))
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Protocol, runtime_checkable

import numpy as np

__all__ = ["Model", "PointMap", "DisplacementMap", "Part", "SurfacePoints", "OnePass", "end_step", "END_STEP_PASSES",
           "OnVoxelGrid", "ConstantStiffness", "FromDisplacement", "InternalVariables", "TangentProjection", "PointSamples",
           "RunState", "begin_run"]


@runtime_checkable
class PointMap(Protocol):
    """A linear map from the node state to the world positions of ``m`` material points."""

    def apply(self, q) -> np.ndarray:
        """Positions (m, 3) for the state q (n, d)."""

    def vjp(self, q, f) -> np.ndarray:
        """Node forces (n, d) of point forces f (m, 3): ``J^T f``."""


@runtime_checkable
class DisplacementMap(Protocol):
    """A :class:`PointMap` that may also map a displacement of the state: when ``linear`` (points, affine
    frames), ``jvp(X, u)`` is the points' displacement for the state ``X + u``, to the digits of ``u``
    (results keep a probe's 1e-17 m on a 1 m body; ``apply(X + u) - apply(X)`` would give 0)."""

    linear: bool

    def jvp(self, q, dq) -> np.ndarray:
        """Point velocities (m, 3) of the state velocity dq (n, d) at q."""


@dataclass(frozen=True, eq=False)
class Part:
    """A part of a model that must be held on its own (a material component, a piece of mesh).

    Attributes
    ----------
    nodes : (k,) int, the model's nodes that move it
    lo, hi : (3,) float, its world bounding box at rest (m)
    labels : tuple of int, the material labels in it
    size : int, how many cells (``cell``) it has
    cell : str, what a cell is in messages ("voxels", "triangles")
    """

    nodes: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    labels: tuple
    size: int
    cell: str = "voxels"

    @classmethod
    def of_components(cls, image, comps, nodes_of, *, cell: str = "voxels") -> list:
        """The parts of a component image ``comps`` (0 outside, 1..k) over ``image``, moved by ``nodes_of[c]``."""
        out = []
        for c, nodes in enumerate(nodes_of):
            mask = comps == c + 1
            ijk = np.argwhere(mask)
            lo = image.index_to_world(ijk.min(axis=0)[None].astype(float))[0]
            hi = image.index_to_world(ijk.max(axis=0)[None].astype(float) + 1.0)[0]
            labels = tuple(sorted(int(x) for x in np.unique(image.labels[mask])))
            out.append(cls(np.asarray(nodes, dtype=np.int64), np.minimum(lo, hi), np.maximum(lo, hi), labels,
                           int(len(ijk)), cell))
        return out


@dataclass(frozen=True, eq=False)
class SurfacePoints:
    """Quadrature points of a model's boundary surface, where tractions and contact act.

    Attributes
    ----------
    points : (m, 3) float, rest positions (m)
    weight : (m,) float, the area each stands for (m^2): sums to the boundary area
    normal : (m, 3) float, outward unit normals at rest
    patch : (m,) int, the surface patch (a voxel face, a triangle) each point lies on
    centre : (P, 3) float, the centre of each patch (regions select patches by their centre)
    """

    points: np.ndarray
    weight: np.ndarray
    normal: np.ndarray
    patch: np.ndarray
    centre: np.ndarray


@runtime_checkable
class Model(Protocol):
    """The interface every model offers (see the module docstring).

    Attributes
    ----------
    kind : NodeKind
        What its nodes are (:mod:`voxflex.deform.models.kinds`): noun, DOFs per node, scene settings.
    node_kind : str
        ``kind.name``, as the result file records it.
    dofs_per_node : int
        d, the numbers per node (3 or 12).
    rest : (n, d) float
        The rest state.
    image : LabelImage
        The label image the model was built on (written to the result file).
    materials : dict label -> Material
        The material of every label present.
    supported_by_contact : bool
        True when obstacles may hold the body (the static support check is skipped).
    n_nodes : int
    constant_tangent : bool
        True when the energy is quadratic in q (the Hessian never changes).
    """

    kind: object
    node_kind: str
    dofs_per_node: int
    rest: np.ndarray
    image: object
    materials: Mapping
    supported_by_contact: bool

    @property
    def n_nodes(self) -> int: ...

    @property
    def constant_tangent(self) -> bool: ...

    def begin_step(self, fraction: float, q_prev, q_start):
        """The state (flat) a step at load factor / time fraction ``fraction`` starts from, given the
        previous state and the solver's start: ``q_start`` itself unless the model must move it
        (contact: obstacles move, the start must be admissible for the barrier)."""

    def advice(self) -> str:
        """A sentence of model-specific advice added to a solver failure, or ''."""

    def describe(self) -> dict:
        """Attributes written to the result file's ``/model`` group (node_kind, count, dofs, samples ...)."""

    def energy(self, q) -> float:
        """Elastic energy (J); inf or NaN where the material is undefined (inverted)."""

    def gradient(self, q) -> np.ndarray:
        """dE/dq, shaped like q (N, N m)."""

    def energy_gradient_hessian(self, q, *, gradient: bool = True, hessian: bool = True):
        """(energy J, gradient (n, d) or None, Hessian (nd, nd) or None).

        The Hessian is a scipy sparse matrix (voxel models) or a dense ndarray (frame
        models, whose stiffness is nearly full); the solvers take either."""

    def hessian(self, q):
        """d²E/dq² (nd, nd): sparse, or a dense ndarray (see :meth:`energy_gradient_hessian`)."""

    def mass_matrix(self, densities: Mapping[int, float], *, lumped: bool = True):
        """Mass matrix (nd, nd) in the DOFs from mapped mass points (kg, kg m, kg m²)."""

    def gravity_force(self, densities: Mapping[int, float], g) -> np.ndarray:
        """Generalised gravity force (n, d): ``J^T (rho g vol)`` at the mass points."""

    def rigid_modes(self) -> np.ndarray:
        """(nd, 6) infinitesimal rigid motions (3 translations, 3 rotations) of the state."""

    def point_mapping(self, points) -> PointMap:
        """Mapping of material points (m, 3) given at rest; InputError outside the material."""

    def boundary_surface(self):
        """The visual layer: (rest vertices (V, 3), triangles (F, 3), PointMap of the vertices)."""

    def load_surface(self, order: int = 2) -> SurfacePoints:
        """Quadrature points of the boundary surface (``order`` x ``order`` per patch) where tractions
        and contact act; InputError when the model has no such surface (say which loads to use)."""

    def volume_points(self):
        """Material points that integrate the volume: (points (m, 3), volume (m,) m³)."""

    def node_points(self, q):
        """(n, 3) the world point a render draws for each node at state q (a frame's origin), or None
        when nodes are not drawn (voxel corners, mesh vertices: the surface shows them)."""

    def sample_fields(self, q) -> dict:
        """What result fields (:mod:`voxflex.deform.models.fields`) are computed from, at state q (n, d):
        ``F`` (s, 3, 3) at the energy's samples, their ``volume`` (s,) m^3 and ``label`` (s,), the
        ``cell`` (s,) each belongs to (``n_cells`` cells, ``cell_kind`` "voxels" or "samples"),
        ``materials`` {label: Material}; on the surface either ``triangle_cell`` (F,) (the cell
        behind each triangle of :meth:`boundary_surface`) or ``surface_F`` (k, 3, 3) (or a callable
        returning it, evaluated only when a field is asked for), ``surface_label`` (k,) and
        ``triangle_point`` (F,) into them.  Arrays may be read-only."""

    def parts(self) -> list:
        """The :class:`Part` s a static solve must hold separately (material components)."""

    def held_dofs(self, lo, hi, components: str) -> np.ndarray:
        """Flat DOFs (sorted) that a fixed box [lo, hi] holds for the given components ("xyz" subset)."""

    def moved_state(self, transform) -> np.ndarray:
        """The state (n, d) of the whole body moved by the affine map ``[A | t]`` (3, 4)."""


# ---------------------------------------------------------------------------
# optional capabilities: small protocols, checked with isinstance
# ---------------------------------------------------------------------------
@runtime_checkable
class OnVoxelGrid(Protocol):
    """Nodes at the corners of a voxel grid: geometric multigrid can coarsen them."""

    dof_grid: object  # TrilinearGrid


@runtime_checkable
class ConstantStiffness(Protocol):
    """A quadratic energy whose stiffness the lean static path assembles once, on the free DOFs only,
    and gives multigrid as element matrices."""

    def constant_stiffness_block(self, free): ...

    def stiffness_elements(self): ...


@runtime_checkable
class FromDisplacement(Protocol):
    """Strains formed from the displacement ``u = q - rest`` itself rather than from the positions q.

    The positions are known to ``eps |x|`` only, so a strain formed from them carries noise of about
    ``eps |x| / h`` (h the voxel or frame spacing): a body far from the origin, or a motion below ~1e-11 of
    its size, loses its digits.  The solvers keep the displacement as their state and hand it over when
    the model has this capability; ``energy_gradient_hessian_u(u)`` equals
    ``energy_gradient_hessian(rest + u)`` in exact arithmetic."""

    def energy_gradient_hessian_u(self, u, *, gradient: bool = True, hessian: bool = True):
        """``energy_gradient_hessian`` at the displacement ``u`` (shaped like q)."""

    def strain_lengths(self) -> np.ndarray:
        """Shaped like q: per DOF, the motion that changes some sample's F by 1.  F = I + grad u is known
        to eps, so the forces resolve motions down to about eps times these (Newton's round-off floor)."""


@runtime_checkable
class DisplacementGradients(Protocol):
    """The displacement's gradient at the samples without the identity added: ``H = F - I``, every digit of a
    strain however small (``F = I + H`` keeps ``eps / |H|`` of it: 2e-9 of a 1e-7 strain)."""

    def displacement_gradients(self, u) -> np.ndarray:
        """H (m, 3, 3) at the samples of :meth:`Model.sample_fields`, in its order, of the displacement u."""


@runtime_checkable
class InternalVariables(Protocol):
    """Internal variables (plastic strains, a friction lag) updated after every converged step."""

    def end_step(self, q) -> bool:
        """The step converged at q (n, d): update the internal variables; True when they changed so that the
        step must be solved again with them, False when they are settled (then they are committed)."""


@runtime_checkable
class RunState(Protocol):
    """State a run leaves behind (plastic strains, where moving obstacles stand, a friction lag):
    :func:`voxflex.simulate` calls :meth:`begin_run` when a scene's run starts, so that a model reused for another
    run starts from rest, not from where the last one ended (the solvers alone continue from it: a load-unload
    sequence of ``solve`` calls keeps its plastic strains)."""

    def begin_run(self) -> None:
        """A run starts at load fraction 0: forget the last run's state."""


@runtime_checkable
class TangentProjection(Protocol):
    """Hessians from per-sample tangents dP/dF projected to positive semi-definite on demand."""

    def set_tangent_projection(self, on: bool) -> bool:
        """Project later Hessians' tangents (``on``) or not; returns whether any tangent is projected."""


@runtime_checkable
class PointSamples(Protocol):
    """An energy integrated at point samples whose deformation gradients a material layer (plasticity) reads."""

    def deformation_gradients(self, q) -> np.ndarray:
        """F (s, 3, 3) at every sample, in the order of ``sample_fields(q)``."""

    def point_sample_refusal(self, labels) -> str:
        """Why the samples of ``labels`` cannot carry internal variables ('' when they can)."""


class OnePass:
    """``energy``, ``gradient`` and ``hessian`` of a model that computes them together in
    ``energy_gradient_hessian(q, *, gradient=True, hessian=True) -> (E, g or None, H or None)``."""

    def energy(self, q) -> float:
        """Energy (J) at state q."""
        return self.energy_gradient_hessian(q, gradient=False, hessian=False)[0]

    def gradient(self, q) -> np.ndarray:
        """dE/dq (N), shaped like q."""
        return self.energy_gradient_hessian(q, hessian=False)[1]

    def hessian(self, q):
        """d2E/dq2 (dense or CSR, as ``energy_gradient_hessian`` builds it)."""
        return self.energy_gradient_hessian(q)[2]


END_STEP_PASSES = 100
"""Re-solves of one step that :func:`~voxflex.deform.solve.stepping.solve` allows while :func:`end_step` still
reports changed internal variables, before it gives up with a ConvergenceError."""


def begin_run(model) -> None:
    """The start-of-run hook: ``model.begin_run()`` for a model with :class:`RunState`, else nothing."""
    if isinstance(model, RunState):
        model.begin_run()


def end_step(model, q) -> bool:
    """The post-convergence hook: ``model.end_step(q)`` for a model with :class:`InternalVariables`, else False.

    The solvers call it after every converged step with the state ``q`` (n, d);
    True means the model's internal variables (plastic strains, a friction lag)
    changed and the step must be solved again with them (at most
    :data:`END_STEP_PASSES` times); False means they are settled and committed.
    """
    return bool(model.end_step(q)) if isinstance(model, InternalVariables) else False
