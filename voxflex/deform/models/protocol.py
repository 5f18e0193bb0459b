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
>>> from voxflex.deform.materials.material import material
>>> from voxflex.deform.models.voxel.model import VoxelModel
>>> model = VoxelModel.from_image(LabelImage(np.ones((2, 1, 1))), {1: material("hooke", young=1.0, poisson=0.3)})
>>> isinstance(model, Model), model.node_kind, model.rest.shape
(True, 'voxel', (12, 3))
"""

from __future__ import annotations

from typing import Mapping, Protocol, runtime_checkable

import numpy as np

__all__ = ["Model", "PointMap", "OnePass", "NODE_KINDS", "IMPLEMENTED_NODE_KINDS", "end_step", "END_STEP_PASSES"]

NODE_KINDS = ("affine", "rigid", "voxel", "membrane")
"""``[nodes] kind`` values: affine frames (12 DOF), rigid frames (6 DOF), voxel-corner points (3 DOF),
the vertices of a membrane's triangle mesh (3 DOF, :mod:`voxflex.deform.models.membrane.model`)."""


IMPLEMENTED_NODE_KINDS = ("affine", "rigid", "voxel", "membrane")
"""The node kinds a scene can be simulated with (rigid frames: static scenes only)."""


@runtime_checkable
class PointMap(Protocol):
    """A linear map from the node state to the world positions of ``m`` material points."""

    def apply(self, q) -> np.ndarray:
        """Positions (m, 3) for the state q (n, d)."""

    def vjp(self, q, f) -> np.ndarray:
        """Node forces (n, d) of point forces f (m, 3): ``J^T f``."""


@runtime_checkable
class Model(Protocol):
    """The interface every model offers (see the module docstring).

    Attributes
    ----------
    node_kind : str
        One of :data:`NODE_KINDS`.
    dofs_per_node : int
        d, the numbers per node (3 or 12).
    rest : (n, d) float
        The rest state.
    image : LabelImage or None
        The label image the model was built on (written to the result file).
    dof_grid : TrilinearGrid or None
        The voxel grid whose corners are the nodes (voxel models: geometric
        multigrid uses it), None for other models.
    supported_by_contact : bool
        True when obstacles may hold the body (the static support check is skipped).
    n_nodes : int
    constant_tangent : bool
        True when the energy is quadratic in q (the Hessian never changes).
    """

    node_kind: str
    dofs_per_node: int
    rest: np.ndarray
    image: object
    dof_grid: object
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

    # Optional (not part of the structural check, so models without internal variables need not define
    # it; call it through :func:`end_step`, whose default is the no-op):
    #
    # def end_step(self, q) -> bool:
    #     """The step converged at the state q (n, d): update the internal variables (plastic strains,
    #     a friction lag) from it.  True when they changed so that the step must be solved again with
    #     them; False when they are settled, and then they are committed as the start of the next step."""

    def describe(self) -> dict:
        """Attributes written to the result file's ``/model`` group (node_kind, count, dofs, ...)."""

    def energy(self, q) -> float:
        """Elastic energy (J); inf or NaN where the material is undefined (inverted)."""

    def energy_gradient_hessian(self, q, *, gradient: bool = True, hessian: bool = True):
        """(energy J, gradient (n, d) or None, Hessian (nd, nd) or None).

        The Hessian is a scipy sparse matrix (voxel models) or a dense ndarray (frame
        models, whose stiffness is nearly full); the solvers take either."""

    def hessian(self, q):
        """d²E/dq² (nd, nd): sparse, or a dense ndarray (see :meth:`energy_gradient_hessian`)."""

    # optional: set_tangent_projection(on: bool) -> bool
    #     Later Hessians built from per-sample tangents dP/dF projected to positive semi-definite
    #     (on) or exact (off, the default); returns whether any tangent is projected.  Models
    #     without it (rigid frames, whose mapping has its own geometric stiffness) stay exact.

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

    def boundary_faces(self):
        """Voxel faces exposed to empty space: (corners (F, 4, 3) at rest, counter-clockwise from
        outside; area (F,) m²; outward normal (F, 3))."""

    def volume_points(self):
        """Material points that integrate the volume: (points (m, 3), volume (m,) m³)."""

    def sample_fields(self, q) -> dict:
        """What result fields (:mod:`voxflex.deform.models.fields`) are computed from, at state q (n, d):
        ``F`` (s, 3, 3) at the energy's samples, their ``volume`` (s,) m^3 and ``label`` (s,), the
        ``cell`` (s,) each belongs to (``n_cells`` cells, ``cell_kind`` "voxels" or "samples"),
        ``materials`` {label: Material}; on the surface either ``triangle_cell`` (F,) (the cell
        behind each triangle of :meth:`boundary_surface`) or ``surface_F`` (k, 3, 3),
        ``surface_label`` (k,) and ``triangle_point`` (F,) into them."""

    def components(self):
        """Material components the model treats as separate parts: (component image (nx, ny, nz) int,
        0 outside, 1..k; k; list of the node indices of each component)."""

    def held_dofs(self, lo, hi, components: str) -> np.ndarray:
        """Flat DOFs (sorted) that a fixed box [lo, hi] holds for the given components ("xyz" subset)."""

    def moved_state(self, transform) -> np.ndarray:
        """The state (n, d) of the whole body moved by the affine map ``[A | t]`` (3, 4)."""


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


def end_step(model, q) -> bool:
    """The post-convergence hook: ``model.end_step(q)`` when the model has one, else False (no internal variables).

    The solvers call it after every converged step with the state ``q`` (n, d);
    True means the model's internal variables (plastic strains, a friction lag)
    changed and the step must be solved again with them (at most
    :data:`END_STEP_PASSES` times); False means they are settled and committed.
    """
    hook = getattr(model, "end_step", None)
    return bool(hook(q)) if callable(hook) else False
