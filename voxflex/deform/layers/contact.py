"""Contact with obstacles: the collision layer, a barrier energy of mapped surface points.

The collision layer is one more mapped layer of the nodes: points on the
body's boundary (at rest), mapped by the model's own point mapping
``x = J q`` (constant J for voxel corners and affine frames), keep away from
the obstacles (:mod:`voxflex.deform.layers.obstacles`) by a smooth barrier of their
signed distance ``d(x)`` (the log barrier of IPC):

    E_c(q) = sum_p a_p kappa b(d_p),   b(d) = -(d - dhat)^2 log(d / dhat) / dhat   for 0 < d < dhat,

zero for ``d >= dhat`` and ``+inf`` for ``d <= 0``; ``a_p`` is the area the
point stands for (m^2), ``kappa`` the stiffness (Pa) and ``dhat`` the
activation distance (m), so ``kappa b`` is an energy per area and a point at
``d = dhat / 2`` is pressed away with about ``1.19 kappa``; under a pressure
``p << kappa`` the gap is ``dhat (1 - sqrt(p / (3 kappa)))``.  The barrier is
C2 at ``dhat`` and infinite at contact, so the Newton solvers' line search
(which rejects a trial step with a non-finite energy) never lets a point
reach or cross an obstacle: that is the step filter.

With the default ``"surface"`` points each drawn triangle also collides with
every sphere at its deepest point (:mod:`voxflex.deform.layers.drawn`), which
takes the vertices' share of the area against that sphere: nothing drawn
enters it.  :mod:`voxflex.deform.layers.contact_checks` refuses or warns about
obstacles the points cannot see.

:class:`ContactModel` wraps any model of the protocol
(:mod:`voxflex.deform.models.protocol`) and adds ``E_c`` to its energy, ``J^T f_c`` to
its gradient and ``J^T B J`` to its Hessian, ``B`` the per-point 3x3 barrier
Hessians ``a kappa (b'' n n^T + b' d2d/dx2)`` (projected to positive
semi-definite unless ``project=False``).  Everything else is forwarded to the
wrapped model.  Obstacles may move (their ``motion``); the solver tells the
wrapper where a step stands with :meth:`ContactModel.begin_step` (or
:meth:`ContactModel.set_time`).

Coulomb friction (obstacles with ``friction = mu > 0``) is the lagged,
smoothed friction of IPC.  At the start of each step (:meth:`begin_step`, from
the previous converged state ``x^n``) every collision point in the barrier's
range freezes its normal force ``lambda = -a kappa b'(d^n)`` (N), the
tangent projector ``P = I - n n^T`` of the obstacle's normal there, and the
point ``xbar`` of the obstacle it touches (``x^n`` carried by the obstacle's
rigid motion over the step).  During the step the friction potential

    D(q) = sum_p mu lambda_p f0(|u_p|),   u_p = P_p (x_p(q) - xbar_p),

with the C1 mollifier ``f0(y) = y^2 / eps - y^3 / (3 eps^2)`` for ``y < eps``
and ``y - eps / 3`` beyond (:func:`friction_mollifier`), enters Newton like
the barrier: ``D`` is convex in x, so its exact Hessian
``mu lambda P (f0'' t t^T + f0'/y (I - t t^T)) P`` (``t = u / y``) is positive
semi-definite and never projected.  A point sliding more than ``eps`` in a
step feels the Coulomb force ``mu lambda`` against its slip; below ``eps`` the
force grows smoothly from 0 (``mu lambda f0'(y)``, ``f0'(y) = 2y/eps - y^2/eps^2``):
static friction is a stiff spring that lets a stuck point creep by at most
``eps`` per step, exactly ``eps (1 - sqrt(1 - F_t / (mu lambda)))`` under a
tangential load ``F_t < mu lambda``.  ``eps`` is the ``slip`` distance (m per step;
default :data:`SLIP_FRACTION` of the barrier distance, i.e. 0.01 % of the
voxel size).  Implicit Euler then creeps slower than ``eps / dt``: for a
creep-velocity bound ``eps_v`` independent of the time step give
``slip = eps_v dt`` (IPC's ``eps_v h``).  The
lag makes each step a minimisation (the potential is fixed during the step),
and friction only removes energy: its work over a step is
``-sum mu lambda f0'(y) y <= 0``.  Before the first :meth:`begin_step` there is
no lag and no friction.

References
----------
M. Li, Z. Ferguson, T. Schneider, T. Langlois, D. Zorin, D. Panozzo, C. Jiang,
D. M. Kaufman.  Incremental Potential Contact.  ACM Trans. Graph. 39(4), 2020.

Example
-------
>>> import numpy as np
>>> from voxflex.image.label_image import LabelImage
>>> from voxflex.deform.materials.constitutive import material
>>> from voxflex.deform.models.voxel.model import VoxelModel
>>> from voxflex.deform.layers.obstacles import Plane
>>> inner = VoxelModel.from_image(LabelImage(np.ones((2, 2, 2)), spacing=(0.1,) * 3),
...                               {1: material("hooke", young=1e4, poisson=0.3)})
>>> model = ContactModel(inner, [Plane(point=(0, 0, -0.0005), normal=(0, 0, 1))], distance=0.001)
>>> force = model.contact_forces(model.rest)          # the plane pushes the bottom face up
>>> bool(force[0, 2] > 0), float(abs(force[0, 0])) < 1e-12
(True, True)
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import scipy.sparse as sp

from ...errors import ConvergenceError, InputError
from ..models.protocol import OnePass
from .base import ModelLayer
from .contact_checks import check_overlap, kept_out, warn_small_obstacles
from .drawn import CURVED_KINDS, deepest_points, distance_hessians
from .obstacles import POINT_RULES, Obstacle, obstacle

__all__ = ["ContactModel", "collision_points", "barrier", "friction_mollifier", "with_contact", "POINT_RULES",
           "DISTANCE_FRACTION", "SLIP_FRACTION"]


DISTANCE_FRACTION = 0.01
"""Default activation distance: this fraction of the smallest voxel spacing (so the gap at rest is below 1 %)."""

VERTEX_SHARE = 0.25
"""Share of the boundary area the ``"surface"`` rule gives to the drawn surface's vertices (the rest stays
with the 2x2 Gauss points of the faces).  Colliding the vertices too keeps what a render draws out of
every half-space obstacle: a box dropped on a plane tilted by 22 degrees sank its corner 6.8 % of a
voxel into it with the face points alone; a triangle whose vertices are above a plane is above it."""

SLIP_FRACTION = 0.01
"""Default friction slip distance ``eps``: this fraction of the activation distance (a stuck point creeps
by less than ``eps`` per step)."""


# ---------------------------------------------------------------------------
# the scalar barrier
# ---------------------------------------------------------------------------
def barrier(d, dhat: float):
    """The log barrier ``b(d) = -(d - dhat)^2 log(d / dhat) / dhat`` and its first two derivatives.

    Parameters
    ----------
    d : (m,) float, metres
    dhat : float, metres (> 0)

    Returns
    -------
    b : (m,) float (m): 0 for d >= dhat, +inf for d <= 0
    db : (m,) float (dimensionless), <= 0
    ddb : (m,) float (1/m), >= 0
    """
    d = np.asarray(d, dtype=float)
    b = np.zeros_like(d)
    db = np.zeros_like(d)
    ddb = np.zeros_like(d)
    act = (d > 0) & (d < dhat)
    x = d[act] / dhat
    lg = np.log(x)
    b[act] = -dhat * (x - 1.0) ** 2 * lg
    db[act] = -(2.0 * (x - 1.0) * lg + (x - 1.0) ** 2 / x)
    ddb[act] = -(2.0 * lg + 4.0 * (x - 1.0) / x - (x - 1.0) ** 2 / x**2) / dhat
    b[d <= 0] = np.inf
    return b, db, ddb


def friction_mollifier(y, eps: float):
    """The friction mollifier ``f0(y)`` of the slip ``y >= 0`` and its derivatives (see the module docstring).

    Parameters
    ----------
    y : (m,) float, metres, >= 0
        Length of the tangential slip over the step.
    eps : float, metres (> 0)
        Slip below which friction is a smooth spring instead of the constant Coulomb force.

    Returns
    -------
    f0 : (m,) float (m): ``y^2/eps - y^3/(3 eps^2)`` below eps, ``y - eps/3`` beyond (C1 at eps)
    f1 : (m,) float: ``f0'``, in [0, 1], 1 at and beyond eps
    f1_over_y : (m,) float (1/m): ``f0'/y``, ``2/eps`` at y = 0
    f2 : (m,) float (1/m): ``f0''``, 0 beyond eps
    """
    y = np.asarray(y, dtype=float)
    below = y < eps
    yb = np.where(below, y, 0.0)
    f0 = np.where(below, yb**2 / eps - yb**3 / (3.0 * eps**2), y - eps / 3.0)
    f1 = np.where(below, 2.0 * yb / eps - yb**2 / eps**2, 1.0)
    f1_over_y = np.where(below, 2.0 / eps - yb / eps**2, 1.0 / np.where(below, 1.0, y))
    f2 = np.where(below, 2.0 / eps - 2.0 * yb / eps**2, 0.0)
    return f0, f1, f1_over_y, f2


# ---------------------------------------------------------------------------
# collision points
# ---------------------------------------------------------------------------
def collision_points(model, points="surface"):
    """Rest positions of the collision points of ``model`` and the area each stands for.

    Parameters
    ----------
    model : Model
    points : "surface", "vertices", int or (m, 3) array
        ``"surface"``: the 2x2 Gauss points of every voxel face exposed to empty space
        (:meth:`Model.load_surface`) and the vertices of the drawn surface (:meth:`Model.boundary_surface`),
        which share the area (:data:`VERTEX_SHARE` to the vertices), so that nothing drawn enters a plane;
        an integer k: k x k Gauss points per face
        (k = 1: the face centres); ``"vertices"``: the vertices of the boundary surface
        (a third of each adjacent triangle's area); an array: these rest points,
        each standing for the mean area of a surface point.

    Returns
    -------
    points : (m, 3) float, metres
    area : (m,) float, m^2 (sums to the boundary area for the named rules)
    """
    if isinstance(points, str):
        if points not in POINT_RULES:
            raise InputError(f"contact points must be one of {', '.join(POINT_RULES)} or a count per face edge, "
                             f"got '{points}'")
        if points == "vertices":
            return _vertex_points(model)
        surface = model.load_surface(2)
        V, share = _vertex_points(model)
        return (np.vstack([surface.points, V]),
                np.concatenate([(1.0 - VERTEX_SHARE) * surface.weight, VERTEX_SHARE * share]))
    elif isinstance(points, (int, np.integer)) and not isinstance(points, bool):
        k = int(points)
        if not 1 <= k <= 8:
            raise InputError(f"contact points per face edge must be in 1..8, got {k}")
    else:
        pts = np.asarray(points, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0 or not np.all(np.isfinite(pts)):
            raise InputError("contact points must be 'surface', 'vertices', a count per face edge, "
                             f"or a finite (m, 3) array, got shape {pts.shape}")
        area = float(np.sum(model.load_surface(1).weight))
        return pts, np.full(len(pts), area / len(pts))
    surface = model.load_surface(k)
    return surface.points, surface.weight


def _vertex_points(model):
    """The drawn surface's rest vertices (V, 3) and the area each stands for (a third of each adjacent
    triangle's)."""
    V, faces, _ = model.boundary_surface()
    V = np.asarray(V, dtype=float)
    tri = V[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    share = np.bincount(np.asarray(faces).ravel(), weights=np.repeat(area / 3.0, 3), minlength=len(V))
    return V, share


def _largest_young(model) -> float | None:
    mats = model.materials
    if not mats:
        return None
    vals = [float(m.parameters.get("young", np.nan)) for m in dict(mats).values() if hasattr(m, "parameters")]
    vals = [v for v in vals if np.isfinite(v) and v > 0]
    return max(vals) if vals else None


def _psd(blocks):
    """Each symmetric 3x3 block projected to positive semi-definite (negative eigenvalues set to 0)."""
    w, V = np.linalg.eigh(blocks)
    return np.einsum("mij,mj,mkj->mik", V, np.maximum(w, 0.0), V)


# ---------------------------------------------------------------------------
# the wrapper
# ---------------------------------------------------------------------------
class ContactModel(OnePass, ModelLayer):
    """A model with a barrier against obstacles (see the module docstring).

    Parameters
    ----------
    inner : Model
        Any model of the protocol (voxel or frame model).
    obstacles : sequence of Obstacle
    points : "surface", "vertices", int or (m, 3) array
        The collision points (see :func:`collision_points`).
    distance : float, metres, optional
        Activation distance ``dhat``; default :data:`DISTANCE_FRACTION` of the
        smallest voxel spacing of ``inner.image``.
    stiffness : float, Pa, optional
        Barrier stiffness ``kappa``; default the largest Young's modulus of the
        inner model's materials.
    project : bool
        Project each point's 3x3 barrier Hessian to positive semi-definite
        (default; exact for planes, where it is already so).  ``False`` gives the
        exact Hessian (the derivative contract tests that one).
    slip : float, metres, optional
        Friction slip distance ``eps`` per step (see the module docstring);
        default :data:`SLIP_FRACTION` of ``distance``.  Used only by obstacles
        with ``friction > 0``.

    Attributes
    ----------
    inner : Model
    obstacles : tuple of Obstacle
    points : (m, 3) float; area : (m,) float
    distance, stiffness, slip : float
    fraction : float
        Where the run stands (0 at the start, 1 at the end): the obstacles' motion.

    Raises
    ------
    InputError
        No obstacle, bad distance, stiffness or slip, the rest state inside an obstacle.
    """

    layer = "contact"
    layer_advice = ("contact: a step that cannot keep every collision point outside the obstacles is refused; "
                    "use more steps or a smaller dt")

    def __init__(self, inner, obstacles: Sequence[Obstacle], *, points="surface", distance=None, stiffness=None,
                 project: bool = True, slip=None):
        obstacles = tuple(obstacles)
        if not obstacles:
            raise InputError("a contact model needs at least one obstacle; give [[obstacle]] tables")
        for i, ob in enumerate(obstacles):
            if not isinstance(ob, Obstacle):
                raise InputError(f"obstacle {i} must be an Obstacle (Plane, Sphere, Box, DistanceField), "
                                 f"got {type(ob).__name__}")
        if distance is None:
            image = inner.image
            if image is None:
                raise InputError("give the contact distance (m): the model has no image to take a voxel size from")
            distance = DISTANCE_FRACTION * float(np.min(image.spacing))
        if isinstance(distance, bool) or not np.isfinite(distance) or distance <= 0:
            raise InputError(f"contact distance must be a number > 0 (m), got {distance!r}")
        if stiffness is None:
            stiffness = _largest_young(inner)
            if stiffness is None:
                raise InputError("give the contact stiffness (Pa): no Young's modulus found in the model's materials")
        if isinstance(stiffness, bool) or not np.isfinite(stiffness) or stiffness <= 0:
            raise InputError(f"contact stiffness must be a number > 0 (Pa), got {stiffness!r}")
        if slip is None:
            slip = SLIP_FRACTION * float(distance)
        if isinstance(slip, bool) or not isinstance(slip, (int, float, np.floating)) or not np.isfinite(slip) \
                or slip <= 0:
            raise InputError(f"contact slip (friction slip distance per step) must be a number > 0 (m), got {slip!r}")
        self.inner = inner
        self.obstacles = obstacles
        self.slip = float(slip)
        self._mu = np.array([ob.friction for ob in obstacles])
        self._lag = None  # the friction lag of the current step (see begin_step); None: no friction
        self._step_start = None  # (q_prev, fraction) of the last begin_step: a retried step keeps its start
        self.distance = float(distance)
        self.stiffness = float(stiffness)
        self.project = bool(project)
        self.points, self.area = collision_points(inner, points)
        self.mapping = inner.point_mapping(self.points)
        self._J = None
        self.fraction = 0.0
        self._tri_lag = None  # the friction lag of the drawn triangles' deepest points (see begin_step)
        self._weight = np.repeat(self.area[:, None], len(obstacles), axis=1)  # (m, k) m^2 per point and obstacle
        self._drawn = self._drawn_triangles(inner, points)
        d = self._distances(self.mapping.apply(inner.rest))[0]
        if np.any(d <= 0):
            p, o = np.unravel_index(int(np.argmin(d)), d.shape)
            raise InputError(f"the body at rest touches or enters obstacle {o} ({obstacles[o].kind}) at "
                             f"{self.points[p].tolist()}; move the obstacle or the object apart")
        if self._drawn is not None and self._triangle_pairs(self.mapping.apply(inner.rest), 0.0) is None:
            o = self._crossed[0]
            raise InputError(f"the drawn surface at rest crosses obstacle {o} ({obstacles[o].kind}) between its "
                             f"vertices (a triangle at {np.round(self._crossed[1], 6).tolist()}); move the obstacle "
                             "or the object apart")
        check_overlap(inner, obstacles)
        warn_small_obstacles(inner, obstacles, self.points, self._drawn is not None)
        self.kept_out = kept_out(points)  # obstacle kinds the barrier keeps out of the drawn triangles

    def _drawn_triangles(self, inner, points):
        """The drawn triangles collided at their deepest point in the curved obstacles (``"surface"`` rule):
        (faces (F, 3) as collision-point indices, area share (F,) m^2, curved obstacle indices), or None.

        Their vertices are the last collision points of the rule; against a curved obstacle the vertices'
        share of the area (:data:`VERTEX_SHARE`) goes to the triangles instead (a triangle's deepest point
        is never above its vertices), so the total stays the boundary area."""
        curved = [o for o, ob in enumerate(self.obstacles) if ob.kind in CURVED_KINDS]
        if not curved or not (isinstance(points, str) and points == "surface"):
            return None
        V, faces, _ = inner.boundary_surface()
        V = np.asarray(V, dtype=float)
        faces = np.asarray(faces, dtype=np.int64)
        if len(faces) == 0:
            return None
        m0 = len(self.points) - len(V)
        tri = V[faces]
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        self._weight[m0:, curved] = 0.0
        return m0 + faces, VERTEX_SHARE * area, np.array(curved, dtype=np.int64)

    supported_by_contact = True  # the obstacles may hold the body: no static support check

    def describe(self) -> dict:
        out = dict(self.inner.describe())
        out.update({"contact_obstacles": len(self.obstacles), "contact_points": len(self.points),
                    "contact_distance": self.distance, "contact_stiffness": self.stiffness})
        if np.any(self._mu > 0):
            out["contact_slip"] = self.slip
        return out

    # -- time ---------------------------------------------------------------------
    def admissible(self, q) -> bool:
        """Whether every collision point of state q (n, d) lies outside every obstacle (d > 0)."""
        x = self.mapping.apply(np.asarray(q, dtype=float))
        return bool(np.all(self._distances(x)[0] > 0)) and (self._drawn is None
                                                            or self._triangle_pairs(x) is not None)

    def begin_run(self) -> None:
        """A run starts: the obstacles back at fraction 0, no step start and no friction lag (a model reused for a
        second run carried its obstacles from where the last run left them: examples/pushed_block.toml's second
        run had no admissible start)."""
        super().begin_run()
        self.set_time(0.0)
        self._step_start = None
        self._lag = None
        self._tri_lag = None

    def begin_step(self, fraction: float, q_prev, q_start):
        """Move the obstacles to ``fraction`` and return a state the barrier admits to start the step from.

        The solver calls it once per step, before Newton, with the previous state
        and its own start (statics: the previous state; implicit Euler: the
        inertial prediction ``q + h v``).  Returns the first of these the
        barrier admits: ``q_start`` itself (the same object); a copy of the
        previous state; the previous state carried along by the step's motion
        of the moving obstacle(s) (every node moved by the obstacle's rigid
        increment; right for one moving obstacle at a time).  The increment
        from there is Newton's; when the start is not ``q_start``, implicit
        Euler's velocity is ``(q_new - q_prev) / h``, not ``v + increment / h``.

        It also refreshes the friction lag from ``q_prev`` (normal forces,
        tangent projectors and touched obstacle points of the step; see the
        module docstring).  A call with the same ``q_prev`` as the last one is
        a retry of that step (a cut load increment): the step keeps its start
        fraction.

        Raises
        ------
        ConvergenceError
            None of them is admissible (e.g. two obstacles closing in on the body
            in one step): use more steps.
        """
        shape = np.shape(self.inner.rest)
        prev_fraction = self.fraction
        q_prev_arr = np.asarray(q_prev, dtype=float).reshape(shape)
        if self._step_start is not None and np.array_equal(self._step_start[0], q_prev_arr):
            prev_fraction = self._step_start[1]  # a retry of the same step from the same state
        self.set_time(fraction)
        self._step_start = (q_prev_arr.copy(), prev_fraction)
        self._lag = self._friction_lag(q_prev_arr, prev_fraction, self.fraction)
        self._tri_lag = self._triangle_friction_lag(q_prev_arr, prev_fraction, self.fraction)
        if self.admissible(np.reshape(q_start, shape)):
            return q_start  # the very object: the solver keeps its velocity bookkeeping
        q_start = np.asarray(q_start, dtype=float)
        q_prev = np.asarray(q_prev, dtype=float)
        if self.admissible(q_prev.reshape(shape)):
            return q_prev.reshape(q_start.shape).copy()
        moving = [ob for ob in self.obstacles if ob.motion is not None]
        q = q_prev.reshape(shape)
        for ob in moving:
            R0, t0 = ob.pose(prev_fraction)
            R1, t1 = ob.pose(fraction)
            R = R1 @ R0.T
            q = _moved(self.inner, q, R, t1 - R @ t0)
        if moving and self.admissible(q):
            return q.reshape(q_start.shape)
        raise ConvergenceError(
            f"contact at fraction {fraction:.4g}: no admissible start state (the obstacles' step motion or the "
            "inertial prediction puts collision points inside an obstacle); use more steps or a smaller dt"
        )

    # -- friction -------------------------------------------------------------------
    def _friction_lag(self, q, s0, s1):
        """The frozen quantities of a step from state q (n, d) at fraction s0 to fraction s1, or None.

        Per active (point, obstacle) pair: point index, obstacle index, ``mu lambda`` (N),
        the tangent projector P (3, 3) and the touched obstacle point ``xbar`` (3,) at s1.
        """
        if not np.any(self._mu > 0):
            return None
        x = self.mapping.apply(q)
        d, n, _ = self._distances(x, s0)
        _, db, _ = barrier(d, self.distance)
        lam = -self.stiffness * self._weight * db  # (m, k) normal force magnitudes (N), >= 0
        act = (lam > 0) & (self._mu[None, :] > 0)
        if not np.any(act):
            return None
        pts, obs = np.nonzero(act)
        P, xbar = self._carried(obs, x[pts].copy(), n[pts, obs], s0, s1)
        return pts, obs, self._mu[obs] * lam[pts, obs], P, xbar

    def _carried(self, obs, xbar, normal, s0, s1):
        """Tangent projectors (p, 3, 3) and touched points (p, 3) of friction pairs at fraction s1, from the
        points ``xbar`` and the obstacles' normals there at s0 (carried by each obstacle's rigid increment)."""
        normal = normal / np.linalg.norm(normal, axis=1)[:, None]
        for o in np.unique(obs):
            ob = self.obstacles[o]
            if ob.motion is None:
                continue
            R0, t0 = ob.pose(s0)
            R1, t1 = ob.pose(s1)
            R = R1 @ R0.T  # the obstacle's rigid increment over the step: y -> R y + t1 - R t0
            sel = obs == o
            xbar[sel] = (xbar[sel] - t0) @ R.T + t1
            normal[sel] = normal[sel] @ R.T
        P = np.eye(3)[None] - normal[:, :, None] * normal[:, None, :]
        return P, xbar

    def _triangle_friction_lag(self, q, s0, s1):
        """The friction lag of the drawn triangles' deepest points (their barycentric coordinates frozen
        over the step), or None: (combination C (p, m) sparse, obstacle indices, ``mu lambda`` (N), P, xbar,
        triangle indices (p,), barycentric coordinates (p, 3))."""
        if self._drawn is None or not np.any(self._mu > 0):
            return None
        x = self.mapping.apply(q)
        pairs = self._triangle_pairs(x, s0)
        if pairs is None:
            return None
        tri, obs, lam, d, n, _ = pairs
        lam_n = -self.stiffness * self._drawn[1][tri] * barrier(d, self.distance)[1]
        act = (lam_n > 0) & (self._mu[obs] > 0)
        if not np.any(act):
            return None
        C = self._combination(tri[act], lam[act])
        P, xbar = self._carried(obs[act], C @ x, n[act], s0, s1)
        return C, obs[act], self._mu[obs[act]] * lam_n[act], P, xbar, tri[act], lam[act]

    def _friction_terms(self, x, *, hessian=True):
        """Friction energy (J), point forces dD/dx (m, 3), Hessian blocks (m, 3, 3) or None, per-obstacle forces
        dD/dx summed (k, 3), for mapped points x (m, 3) under the current lag."""
        k = len(self.obstacles)
        if self._lag is None:
            return 0.0, None, None, np.zeros((k, 3))
        pts, obs, w, P, xbar = self._lag
        energy, g, B = self._friction_pairs(x[pts], w, P, xbar, hessian)
        m = len(x)
        forces = np.zeros((m, 3))
        np.add.at(forces, pts, g)
        per_obstacle = np.zeros((k, 3))
        np.add.at(per_obstacle, obs, g)
        blocks = None
        if hessian:
            blocks = np.zeros((m, 3, 3))
            np.add.at(blocks, pts, B)
        return energy, forces, blocks, per_obstacle

    def _friction_pairs(self, xf, w, P, xbar, hessian):
        """Friction energy (J), forces dD/dx (p, 3) and Hessian blocks (p, 3, 3) or None of the friction pairs
        at points xf (p, 3) under weights ``mu lambda`` w (p,), projectors P and touched points xbar."""
        u = np.einsum("pij,pj->pi", P, xf - xbar)  # tangential slip (in the tangent plane)
        y = np.linalg.norm(u, axis=1)
        f0, f1, f1y, f2 = friction_mollifier(y, self.slip)
        energy = float(np.sum(w * f0))
        g = (w * f1y)[:, None] * u  # dD/dx per pair: mu lambda f0'(y) u / y (u lies in the tangent plane)
        B = None
        if hessian:
            # P (f0'' t t^T + f0'/y (I - t t^T)) P = f0'/y P + (f0'' - f0'/y) u u^T / y^2 (P u = u)
            safe = np.where(y > 0, y, 1.0)
            uu = np.where(y[:, None, None] > 0, u[:, :, None] * u[:, None, :] / safe[:, None, None] ** 2, 0.0)
            B = w[:, None, None] * (f1y[:, None, None] * P + (f2 - f1y)[:, None, None] * uu)
        return energy, g, B

    def _triangle_friction_terms(self, x, *, hessian=True):
        """Friction of the drawn triangles' deepest points: energy (J), point forces (m, 3), (triangles, blocks
        (p, 9, 9)) or None, per-obstacle forces (k, 3), under the current lag."""
        k = len(self.obstacles)
        if self._tri_lag is None:
            return 0.0, None, None, np.zeros((k, 3))
        C, obs, w, P, xbar, tri, lam = self._tri_lag
        energy, g, B = self._friction_pairs(C @ x, w, P, xbar, hessian)
        per_obstacle = np.zeros((k, 3))
        np.add.at(per_obstacle, obs, g)
        hess = None
        if hessian:  # the frozen point l @ vertices: blocks l_i l_j B on the vertices
            hess = (tri, np.einsum("pi,pj,pab->piajb", lam, lam, B).reshape(-1, 9, 9))
        return energy, np.asarray(C.T @ g), hess, per_obstacle

    def friction_energy(self, q) -> float:
        """The friction potential D (J) of state q (n, d) under the current step's lag (0 without friction)."""
        x = self.mapping.apply(np.asarray(q, dtype=float))
        return self._friction_terms(x, hessian=False)[0] + self._triangle_friction_terms(x, hessian=False)[0]

    # -- energy ---------------------------------------------------------------------
    def _distances(self, x, fraction=None):
        """d (m, k), gradients (m, k, 3), Hessians (m, k, 3, 3) of the points x against every obstacle."""
        s = self.fraction if fraction is None else fraction
        out = [ob._distance_impl(x, s) for ob in self.obstacles]
        return (np.stack([o[0] for o in out], axis=1), np.stack([o[1] for o in out], axis=1),
                np.stack([o[2] for o in out], axis=1))

    def _point_terms(self, q, fraction=None, *, hessian=True, exact=False):
        """Barrier energy (J), point forces dE/dx (m, 3) and Hessian blocks (m, 3, 3) at state q, per obstacle."""
        x = self.mapping.apply(q)
        d, n, Hd = self._distances(x, fraction)
        b, db, ddb = barrier(d, self.distance)
        w = self.stiffness * self._weight  # (m, k) Pa m^2
        if np.any(np.isinf(b)):
            return np.inf, None, None, None
        energy = float(np.sum(w * b))
        per_obstacle = (w * db)[:, :, None] * n  # (m, k, 3) dE/dx per obstacle
        blocks = None
        if hessian:
            act = (db != 0) & (w > 0)
            blocks = np.zeros((len(x), 3, 3))
            if np.any(act):
                pts, obs = np.nonzero(act)
                B = (w[pts, obs] * ddb[pts, obs])[:, None, None] * n[pts, obs, :, None] * n[pts, obs, None, :] \
                    + (w[pts, obs] * db[pts, obs])[:, None, None] * Hd[pts, obs]
                if self.project and not exact:
                    B = _psd(B)
                np.add.at(blocks, pts, B)
        return energy, per_obstacle.sum(axis=1), blocks, per_obstacle

    # -- the drawn triangles against curved obstacles (voxflex.deform.layers.drawn) ------
    def _combination(self, tri, lam):
        """Sparse (p, m): row i is the deepest point of triangle ``tri[i]``, ``lam[i] @`` its vertices' points."""
        p = len(tri)
        return sp.csr_matrix((lam.ravel(), (np.repeat(np.arange(p), 3), self._drawn[0][tri].ravel())),
                             shape=(p, len(self.points)))

    def _triangle_pairs(self, x, fraction=None):
        """The (triangle, curved obstacle) pairs within the barrier's range at mapped points x (m, 3): triangle
        and obstacle indices, barycentric coordinates (p, 3) of each deepest point, its distance d (p,), the
        obstacle's gradient (p, 3) and Hessian (p, 3, 3) there; None when a triangle touches or crosses an
        obstacle (``self._crossed`` then names the obstacle and the triangle's centre)."""
        s = self.fraction if fraction is None else fraction
        faces, _, curved = self._drawn
        tri = x[faces]
        centre = tri.mean(axis=1)
        reach = np.linalg.norm(tri - centre[:, None, :], axis=2).max(axis=1)
        out = []
        for o in curved:
            ob = self.obstacles[o]
            # the signed distance is 1-Lipschitz: a triangle whose centre is farther than its reach plus the
            # barrier's range has no point in that range
            near = np.flatnonzero(ob._distance_impl(centre, s)[0] - reach < self.distance)
            if len(near) == 0:
                continue
            lam, crosses = deepest_points(tri[near], ob, s)
            d, n, H = ob._distance_impl(np.einsum("pv,pvc->pc", lam, tri[near]), s)
            bad = crosses | (d <= 0)
            if np.any(bad):
                self._crossed = (int(o), centre[near[np.argmax(bad)]])
                return None
            act = d < self.distance
            out.append((near[act], np.full(int(act.sum()), o), lam[act], d[act], n[act], H[act]))
        if not out:
            return (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros(0),
                    np.zeros((0, 3)), np.zeros((0, 3, 3)))
        return tuple(np.concatenate(parts) for parts in zip(*out))

    def _triangle_terms(self, q, fraction=None, *, hessian=True, exact=False):
        """Barrier energy (J), point forces (m, 3), (triangles, blocks (p, 9, 9)) or None, and per-obstacle forces
        dE/dx (k, 3) of the drawn triangles' deepest points; (inf, None, None, None) when one crosses."""
        k = len(self.obstacles)
        m = len(self.points)
        if self._drawn is None:
            return 0.0, np.zeros((m, 3)), None, np.zeros((k, 3))
        x = self.mapping.apply(q)
        pairs = self._triangle_pairs(x, fraction)
        if pairs is None:
            return np.inf, None, None, None
        tri, obs, lam, d, n, Hd = pairs
        b, db, ddb = barrier(d, self.distance)
        w = self.stiffness * self._drawn[1][tri]  # Pa m^2
        g = (w * db)[:, None] * n  # dE/dp per pair
        forces = np.zeros((m, 3))
        np.add.at(forces, self._drawn[0][tri].ravel(), (lam[:, :, None] * g[:, None, :]).reshape(-1, 3))
        per_obstacle = np.zeros((k, 3))
        np.add.at(per_obstacle, obs, g)
        hess = None
        if hessian and len(tri):
            grad = (lam[:, :, None] * n[:, None, :]).reshape(-1, 9)  # dd/d(vertices), the deepest point held
            B = (w * ddb)[:, None, None] * grad[:, :, None] * grad[:, None, :] \
                + (w * db)[:, None, None] * distance_hessians(lam, x[self._drawn[0][tri]], n, Hd)
            if self.project and not exact:
                B = _psd(B)
            hess = (tri, B)
        return float(np.sum(w * b)), forces, hess, per_obstacle

    def _triangle_hessian(self, q, tri, blocks):
        """``J_t^T B J_t`` (N, N) over drawn triangles ``tri`` (p,) with blocks (p, 9, 9) on their vertices'
        points (vertex-major coordinates)."""
        J = self._jacobian(q)
        rows = (3 * self._drawn[0][tri][:, :, None] + np.arange(3)).ravel()
        Jt = J[rows]
        p = len(tri)
        B = sp.bsr_matrix((blocks, np.arange(p), np.arange(p + 1)), shape=(9 * p, 9 * p)).tocsr()
        return (Jt.T @ (B @ Jt)).tocsr()

    def _jacobian(self, q):
        if self._J is None or not self.mapping.constant_jacobian:
            J = self.mapping.jacobian(q)
            if not self.mapping.constant_jacobian:
                return J
            self._J = J
        return self._J

    def barrier_energy(self, q, fraction=None) -> float:
        """The barrier energy E_c (J) of state q (n, d) (inf when a point touches or enters an obstacle, or a
        drawn triangle a curved one)."""
        q = np.asarray(q, dtype=float)
        return self._point_terms(q, fraction, hessian=False)[0] + self._triangle_terms(q, fraction, hessian=False)[0]

    def energy_gradient_hessian(self, q, *, gradient: bool = True, hessian: bool = True, exact: bool = False,
                                u=None):
        """(energy J, gradient (n, d) or None, Hessian CSR (nd, nd) or None) of the inner model plus the barrier.

        ``exact=True`` skips the positive semi-definite projection of the barrier
        blocks (the true Hessian).  Where a collision point touches or enters an
        obstacle the energy is inf and the gradient and Hessian are None.  ``u`` (= q - rest): the inner
        model's strains from the displacement (the layer's displacement form, :class:`ModelLayer`); the
        barrier reads the positions.
        """
        q = np.asarray(q, dtype=float)
        Ec, fpts, blocks, _ = self._point_terms(q, hessian=hessian, exact=exact)
        if not np.isfinite(Ec):
            return np.inf, None, None
        Et, ft, tri_hessians, _ = self._triangle_terms(q, hessian=hessian, exact=exact)
        if not np.isfinite(Et):
            return np.inf, None, None
        Ec, fpts, tri_hessians = Ec + Et, fpts + ft, [tri_hessians]
        if self._tri_lag is not None:
            Ef, ff, fh, _ = self._triangle_friction_terms(self.mapping.apply(q), hessian=hessian)
            Ec, fpts = Ec + Ef, fpts + ff
            tri_hessians.append(fh)
        if self._lag is not None:  # friction: its blocks are PSD as they are (a convex potential)
            Ef, ff, fb, _ = self._friction_terms(self.mapping.apply(q), hessian=hessian)
            Ec = Ec + Ef
            fpts = fpts + ff
            if hessian:
                blocks = blocks + fb
        E, g, H = self._inner_terms(q, u, gradient, hessian)
        E = E + Ec
        act = np.flatnonzero(np.any(fpts != 0, axis=1)) if fpts is not None else np.zeros(0, dtype=np.int64)
        if gradient and len(act):
            g = g + self.mapping.vjp(q, fpts)
        if hessian and self._lag is not None:  # a stuck point has a zero force but a stiff Hessian
            act = np.union1d(act, self._lag[0])
        if hessian and len(act):
            Hb = self._barrier_hessian(q, blocks, act)
            H = H + Hb.toarray() if isinstance(H, np.ndarray) else H + Hb  # frame models give dense Hessians
        for th in tri_hessians if hessian else ():
            if th is not None and len(th[0]):
                Hb = self._triangle_hessian(q, *th)
                H = H + Hb.toarray() if isinstance(H, np.ndarray) else H + Hb
        return E, g, H

    def _barrier_hessian(self, q, blocks, act):
        """``J_a^T B_a J_a`` (N, N) over the active points ``act``."""
        J = self._jacobian(q)
        rows = (3 * act[:, None] + np.arange(3)).ravel()
        Ja = J[rows]
        k = len(act)
        B = sp.bsr_matrix((blocks[act], np.arange(k), np.arange(k + 1)), shape=(3 * k, 3 * k)).tocsr()
        return (Ja.T @ (B @ Ja)).tocsr()

    # -- forces -----------------------------------------------------------------------
    def contact_forces(self, q, fraction=None) -> np.ndarray:
        """Total force (N) each obstacle exerts on the body at state q (n, d): (obstacles, 3).

        The sum of ``-a kappa b'(d) n`` over the collision points (pointing out of
        the obstacle), plus the friction forces ``-dD/dx`` of the current step's
        lag (tangent to the obstacle); ``fraction`` places moving obstacles for the
        barrier (default: the current :attr:`fraction`; the friction lag is the
        step's).  NaN where the state is not admissible.
        """
        q = np.asarray(q, dtype=float)
        _, _, _, per = self._point_terms(q, fraction, hessian=False)
        per_tri = self._triangle_terms(q, fraction, hessian=False)[3]
        if per is None or per_tri is None:
            return np.full((len(self.obstacles), 3), np.nan)
        return -per.sum(axis=0) - per_tri + self.friction_forces(q)

    def friction_forces(self, q) -> np.ndarray:
        """The friction part (N) of :meth:`contact_forces` at state q (n, d): (obstacles, 3)."""
        x = self.mapping.apply(np.asarray(q, dtype=float))
        return -self._friction_terms(x, hessian=False)[3] - self._triangle_friction_terms(x, hessian=False)[3]


def _moved(model, q, R, t):
    """State q (n, d) with the whole body moved by x -> R x + t (voxel corners or affine frames)."""
    q = np.asarray(q, dtype=float)
    if model.dofs_per_node == 3:
        return q @ R.T + t
    if model.dofs_per_node == 12:
        out = np.empty_like(q)
        A = q[:, :9].reshape(-1, 3, 3)
        out[:, :9] = np.einsum("ij,njk->nik", R, A).reshape(-1, 9)
        out[:, 9:] = q[:, 9:] @ R.T + t
        return out
    raise InputError(f"cannot move a state of {model.dofs_per_node} DOFs per node with an obstacle")


def with_contact(model, scene, *, project: bool = True):
    """``model`` wrapped in a :class:`ContactModel` for the scene's ``[[obstacle]]`` tables and ``[contact]``.

    Returns ``model`` unchanged when the scene has no obstacle or ``model`` is
    a ContactModel already.  The scene is
    read by attribute (``scene.obstacles``: kind, parameters, friction, motion;
    ``scene.contact``: distance, stiffness, points), so this stage does not
    import the scene module.
    """
    specs = tuple(getattr(scene, "obstacles", ()) or ())
    if not specs or isinstance(model, ContactModel):  # nothing to add, or added already (idempotent)
        return model
    contact = getattr(scene, "contact", None)
    obstacles = [obstacle(s.kind, **s.parameters()) for s in specs]
    kwargs = {}
    if contact is not None:
        kwargs = {"points": contact.points, "distance": contact.distance, "stiffness": contact.stiffness}
    return ContactModel(model, obstacles, project=project, **kwargs)
