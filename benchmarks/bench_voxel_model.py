"""Benchmark: the full-resolution voxel model against scikit-fem (and warp.fem) on the shared cantilever.

Problems (beam [0,4]x[0,1]x[0,1], x = 0 clamped, rho g = 9.81 along -z, nu = 0.3):

1. linear (Hooke, small strain), E = 1e4, 64x16x16 voxels (56k DOF), one solve;
2. large-deflection Neo-Hooke, E = 1e3, 32x8x8 voxels, 5 load steps, Newton.

Peers: scikit-fem (a test dependency) and warp.fem (optional: ``pip install
warp-lang``, checked with 1.19.0 on the CPU, see ``_warp_cantilever.py``; its
rows are skipped when it is missing).  Every code is warmed first (the same
problem on an 8x2x2 beam: voxflex's numba kernels, scikit-fem's and
warp.fem's code paths; warp's compile time is printed apart), then timed 3
times (``--repeat``) round-robin across the codes of a row (voxflex, scikit-fem,
warp.fem, voxflex, ...: a slow spell of the host falls on every code alike; run
back to back, one code's three repeats once all fell in one, and the same
Jacobi-CG solve read 0.82x in one run and 1.19x the next): the tables give the
min and the median of the totals; a
peer's runs serve both tables (its solver is the same in both).  The load
average is printed after each problem: on the shared 2-core machine other
work inflates every wall time, so the CPU seconds of each call
(``time.process_time``, every thread of the process, warp's compile
excluded as in the wall time) are given too, with their ratios: less
sensitive to other processes' load, but they count BLAS threads that spin.  Two tables:

* **same solver**: every code solves its own assembled matrices with the same
  method and tolerance (``voxflex.deform.solve.linear.solve_linear``): Jacobi-CG
  at rtol 1e-8 (linear beam), sparse LU with the MMD ordering (Neo-Hooke), and
  geometric multigrid-CG (both problems; voxflex's fastest solver for voxel
  grids), so the ratio is the model and assembly.  Multigrid needs the voxel
  grid in voxflex's DOF numbering: for each peer and size, once and outside the
  timed runs, :class:`VoxelOrder` matches the peer's nodes to voxflex's nodes of
  the same beam (grid indices ``round(x / h)``); each solve reorders the peer's
  free-DOF matrix and right-hand side to voxflex's free-DOF order (``P A P^T``),
  makes the call voxflex makes (``method="multigrid"``, ``grid=model.grid``,
  ``free=...``) and reorders the solution back.  That reordering is an adapter
  cost none of the codes would pay natively: it is timed apart (column
  ``permute s``) and left out of the peer's solve and total.  On the linear
  beam voxflex also passes ``elements=model.stiffness_elements()``, as its own
  ``solve`` does for constant-tangent models: the first coarse level is then
  summed from its voxel element matrices, and the finest level's sweeps and
  products are applied from the voxel stencil instead of the stored entries
  (``multigrid.VoxelStencil``).  These are the same matrices (to round-off) that
  the peers' sparse products form from their assembled ones, and the
  Gauss-Seidel sweeps run in the same row order, so the cycle and the
  iterations are the same.  What differs is how each code applies its own
  operator, which is part of each code's solve time.
  Every run builds
  its hierarchy from its own matrix (``multigrid.clear_cache()`` at the start of
  each run, voxflex's and the peers'; Newton iterations within a run reuse the
  prolongations, as in voxflex).  Self-checks: the reordered 8x2x2 linear
  stiffness of each peer equals voxflex's free-DOF block to 1e-12 relative
  (printed; a wrong node match would differ by O(1)), and every reordered solve
  satisfies the peer's own system to the solver's residual.  In the Neo-Hooke
  multigrid row the peers' Newton solves use voxflex's inexact-Newton tolerance
  (:func:`newton_rtol`: the forcing term ``min(0.1, |r| / scale)``, each code's
  own convergence scale) since voxflex's Newton uses it; with LU the tolerance
  does not matter.  ``fallbacks`` counts iterative solves that missed rtol and
  were answered by the direct solver (``solve_linear``'s fallback, the same for
  every code).  ``--shared-solvers cg,direct,multigrid`` (the default) picks the
  rows; ``--no-skfem`` skips scikit-fem (~60 s per Neo-Hooke run);
* **best solver each** (labelled as such): voxflex with geometric multigrid-CG
  (linear) / its ``auto`` rule (Neo-Hooke), the peers with the fastest of the
  shared methods that needs no grid (Jacobi-CG for the linear beam, LU for
  Neo-Hooke).

Measured on 2026-12-04 after the neo-Hookean element stiffness from three coefficients per sample
(``--repeat 3 --tables-only``, load average 0.9-1.0, CPU seconds min, ratio peer / voxflex): Jacobi-CG
voxflex 0.91, warp.fem 1.55 (1.70x), scikit-fem 4.79 (5.25x); linear multigrid-CG voxflex 0.18, warp.fem
0.95 (5.21x, median 5.20x), scikit-fem 4.16 (22.8x); Neo-Hooke sparse LU voxflex 6.07, warp.fem 10.95
(1.81x), scikit-fem 27.3 (4.49x); Neo-Hooke multigrid-CG voxflex 0.86 (31 Newton, 130 CG), warp.fem 6.93
(8.06x, median 7.53x; wall 8.83x, 8.55x), scikit-fem 24.1 (28.0x); best each: linear warp.fem 8.49x,
Neo-Hooke ``auto`` 0.81 (warp.fem 13.5x).  The whole host ran faster than on 2026-12-02 (every code).

Measured on 2026-12-02 after the stale coarse levels, the first coarse level from the element
matrices, the voxel stencil for the finest level, the compiled pattern and free-DOF gather and the
single-precision cycle (``--repeat 3 --tables-only``, a 0.5 s pause before each timed run, load
average 0.8-1.0, CPU seconds min, ratio peer / voxflex): Jacobi-CG voxflex 1.28, warp.fem 1.98
(1.55x), scikit-fem 7.58 (5.9x); linear multigrid-CG voxflex 0.27 (12 iterations; assembly 0.04,
solve 0.22), warp.fem 1.19 (4.32x, median 3.85x; wall 4.23x min, 3.79x median; assembly 0.74),
scikit-fem 6.92 (25x); Neo-Hooke sparse LU voxflex 9.88, warp.fem 19.9 (2.01x), scikit-fem 56.3
(5.7x); Neo-Hooke multigrid-CG voxflex 1.65 (31 Newton, 129 CG), warp.fem 11.1 (6.73x, median 6.49x;
wall 7.51x, 7.21x; 30 Newton, 125 CG), scikit-fem 50.9 (31x); best each: linear warp.fem 7.20x,
Neo-Hooke ``auto`` 1.75 (warp.fem 11.4x).  Runs earlier the same morning, before the stencil:
linear multigrid-CG voxflex 0.47, warp.fem 1.57 (3.32x); with the stale coarse levels only 0.64
against 1.51 (2.35x).

Measured on 2026-12-02 after the cubic coarsening rule (``multigrid.MAX_COARSE_CUBIC``), the in-place
material tangent and the half-computed voxel stiffness (``--repeat 3 --tables-only``, load average
0.7-1.0, CPU seconds min, ratio peer / voxflex): Jacobi-CG voxflex 2.19, warp.fem 2.77 (1.26x),
scikit-fem 10.36 (4.7x); linear multigrid-CG voxflex 0.84 (12 iterations), warp.fem 1.56 (1.87x;
wall 2.16x), scikit-fem 9.57 (11.4x); Neo-Hooke sparse LU voxflex 11.5, warp.fem 21.5 (1.87x),
scikit-fem 60.4 (5.2x); Neo-Hooke multigrid-CG voxflex 2.53 (31 Newton, 107 CG iterations), warp.fem
13.8 (5.47x; wall 5.98x min, 6.06x median; 30 Newton, 89 CG), scikit-fem 61.8 (24x); best each:
linear warp.fem 3.3x, Neo-Hooke ``auto`` 2.08 (warp.fem 10.3x).  The host ran about twice as fast in
a run 20 minutes before (the Jacobi-CG solve 1.05 against 1.99 s): Neo-Hooke multigrid-CG voxflex 2.49,
warp.fem 12.47 (5.02x; wall 5.50x min, 6.37x median); linear multigrid-CG (13 iterations, before the
1/32 fraction) voxflex 0.49, warp.fem 1.23 (2.53x).

Measured earlier on 2026-12-02 after the coarse level's sparse LU, codes timed round-robin
(``--repeat 3 --tables-only``, load average 0.2-1.0, CPU seconds min, ratio peer / voxflex):
Jacobi-CG voxflex 1.73, warp.fem 3.05 (1.76x), scikit-fem 9.24 (5.3x); linear multigrid-CG
voxflex 0.75, warp.fem 1.71 (2.3x), scikit-fem 7.09 (9.4x); Neo-Hooke sparse LU voxflex 10.6,
warp.fem 18.4 (1.7x), scikit-fem 64.9 (6.1x); Neo-Hooke multigrid-CG voxflex 3.13, warp.fem
12.4 (3.96x; wall 4.19x min, 3.7x median), scikit-fem 55.2 (17.6x); best each: linear warp.fem
4.0x, Neo-Hooke ``auto`` 2.52 s (warp.fem 7.3x).  A run an hour before with each code's repeats
back to back read 0.82x for the Jacobi-CG row (the host slowed during voxflex's three runs) and
3.9x / 4.15x for Neo-Hooke multigrid.

Measured before (``--repeat 3 --tables-only``, warp-lang 1.19.0, scikit-fem 12.0.2,
load average 1.35 before, 1.6-2.1 during and after on the 2 shared cores, CPU
seconds min / median, ratio peer / voxflex of the min): same solver for all,
linear 64x16x16 Jacobi-CG: voxflex 1.16 / 1.17, warp.fem 1.76 / 1.82 (1.51x),
scikit-fem 6.84 / 7.58 (5.9x); same solver for all, multigrid-CG: voxflex
0.55 / 0.55 (12 iterations in every code), warp.fem 1.38 / 1.52 (2.5x; wall
2.65x), scikit-fem 6.72 / 7.46 (12.2x), reordering 0.02 s (warp) and 0.05 s
(scikit-fem) apart; Neo-Hooke 32x8x8 sparse LU: voxflex 9.48 / 10.76,
warp.fem 15.40 / 15.58 (1.6x), scikit-fem 50.3 / 50.5 (5.3x); same solver for
all, multigrid-CG: voxflex 2.73 / 2.75 (31 Newton, 99 CG iterations), warp.fem
10.38 / 10.52 (3.8x; 29 Newton, 81 CG), scikit-fem 45.9 / 46.5 (16.8x); no
fallback to direct in any code.  Best solver each: voxflex multigrid-CG 0.55
(warp 3.2x, scikit-fem 12.4x) and Neo-Hooke ``auto`` (multigrid-CG at 7776
unknowns) 2.61 / 2.67 (warp 5.9x, scikit-fem 19x).  Every code's tip u_z is
-0.391219 (linear) and -2.687096 (Neo-Hooke) with every solver.  With one
solver for all, its time bounds the ratio: with multigrid-CG warp.fem's build
and assembly (0.92 s wall) plus its solve (0.54 s: the shared 0.39 s solve,
the conversion to scipy and the free-DOF block) make 1.46 s, and voxflex at
zero assembly would still take 0.40 s (build and solve), so the linear ratio
cannot pass 3.65x while the solve is shared: 4x needs a shared solve of about
0.14 s.  The Neo-Hooke ratio (3.8x) is warp.fem's assembly (8.6 s of its
10.3 s) over voxflex's whole Newton run.  Jacobi-CG takes the same 318-319
iterations (~1 s) in every code; 30 LU factorisations of 7776 unknowns are
most of voxflex's 9.5 s.

Columns: build = mesh/model and sparsity; assemble = energy, gradient and
stiffness (Newton: every tangent and residual; voxflex's Newton runs have
theirs in solve, all but one assembly); solve = the linear solves (the peers'
include the conversion to a scipy matrix and the free-DOF block); permute =
the multigrid adapter above (not in total).
Then the **scaling series** of the linear beam 16x4x4 ... 128x32x32 solved by
multigrid-CG and Jacobi-CG (rtol 1e-8): seconds (min/median), iterations,
peak traced memory of the solve (``tracemalloc``, numpy arrays included) per
DOF, and the exponent of a least-squares fit time ~ DOF^p.

    python benchmarks/bench_voxel_model.py [--quick] [--repeat 3] [--tables-only] [--shared-solvers LIST]
        [--no-skfem] [--colamd] [--memory NXxNYxNZ] [--big] [--plate [LIST]]

``--plate`` runs only the one-voxel-thick neo-Hooke plate (64x64x1 voxels of 1/64 m, 25,350 DOF,
E = 1e5 Pa, nu = 0.45, clamped along x = 0, gravity, 5 load steps) with each linear solver of LIST
(default ``auto,direct,cg``), warmed, ``--repeat`` runs each round-robin.  Measured on 2026-12-02
(``--plate --repeat 3``, load average 0.4-1.0, total seconds min / median): ``auto`` (multigrid-CG)
13.8 / 14.0 s, 59 Newton and 876 CG iterations; sparse LU 35.1 / 36.5 s, 56 Newton iterations;
Jacobi-CG 190.2 / 226.7 s, 89 Newton and 161,623 CG iterations; the same largest sag, 0.1726 m, with
every solver.

``--quick`` runs 32x8x8 / 16x4x4 and the series to 64x16x16; ``--colamd``
adds scipy's default splu ordering (slow: ~40 s); ``--memory 128x44x44`` only
measures time and peak resident memory (``resource.getrusage``) of building,
assembling and solving a linear beam of that many voxels in this fresh
process, through ``voxflex.deform.solve.stepping.solve`` (``--solver``, default
Jacobi-CG), which takes the lean path for this constant-tangent static
problem: ``VoxelModel.constant_stiffness_block`` (the free-DOF block
assembled and compacted in place, no full matrix kept) and gradients
matrix-free (above ``DIRECT_FALLBACK_MAX`` unknowns with multigrid not even the
block: ``VoxelModel.constant_stiffness_operator``, applied through the voxel
stencil); ``--big`` does the same with multigrid-CG for a 256x90x90 beam
(2.07 million voxels, 6.4 million DOF) and prints the peak bytes per DOF
(refused when /proc/meminfo shows under 1.3x :data:`BIG_BYTES_PER_DOF` times
the DOF available); the run ends with a check that the reactions carry the
load (matrix-free gradient).  ``--cli`` runs ``--big`` or ``--memory`` as a
scene through ``voxflex simulate`` in a fresh process instead (the wall time,
the Newton iterations' share from ``--verbose``, the child's peak RSS).
Measured on 2026-12-03 after the matrix-free block (load average 2.1-2.9, 2
shared cores): ``--big``: 16 iterations, solve() 48.7 s, total 60.9 s, peak
4.06 GB = 666 bytes/DOF, tip u_z -0.392704 m, reactions equal to the load to 7
digits; ``--big --cli``: 6,384,651 DOF, 13 iterations (the scene's box clamps
its x = 0 face the same way; Newton's tolerance differs), command 70.4 s wall
(model 6.9 s, the Newton iteration 36.9 s), peak 5.87 GB = 964 bytes/DOF (the
recorder's per-sample F of the final state, 1.7 GB, is the difference).  Peak resident memory of
``solve`` at 128x32x32 (/proc/self/status VmHWM, fresh process): ``auto``
(multigrid-CG) 3443 bytes/DOF before it took the lean path, 2122 after;
Jacobi-CG 1686 before.  Measured with --big on this 2-core machine
(shared, 38 % of the CPU for the run): 6,384,651 DOF, multigrid-CG 16
iterations to 4.4e-9, solve 260 s wall, total 393 s, peak RSS 8.67 GB =
1423 bytes/DOF (the 128x32x32 path before: 3041), reactions equal to the
load on the free nodes to 7 digits.  Again on 2026-12-02, alone on the machine, after the element
first level, the voxel stencil and the single-precision cycle (which stays double at this size):
16 iterations, solve 104 s, total 113 s, peak 9.71 GB = 1595 bytes/DOF; the code before them, run
in the same hour, 188 s and 197 s (its kernels compiled in the run), 9.08 GB = 1491 bytes/DOF.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

TIP = np.array([4.0, 0.5, 0.5])


def _beam_image(nx):
    from voxflex.image.label_image import LabelImage

    ny = nz = nx // 4
    return LabelImage(np.ones((nx, ny, nz)), spacing=(4 / nx, 1 / ny, 1 / nz))


class VoxelOrder:
    """A peer's free DOFs put in voxflex's free-DOF order of the same beam, for the shared multigrid-CG.

    Geometric multigrid needs the voxel grid the unknowns live on, in voxflex's
    numbering (``3 * node + component`` of ``VoxelModel.rest``, free DOFs
    sorted).  Built once per code and size, outside the timed runs: each peer
    node is matched to the voxflex node at the same grid position (integer
    indices ``round(x / h)``), giving ``q`` with ``q[i]`` = the position, in the
    peer's free-DOF order, of voxflex's free DOF ``i``.  :meth:`solve` then
    solves ``A[q][:, q] y = b[q]`` (``P A P^T``) with the same call voxflex makes
    and returns ``x[q] = y``; the seconds of the reordering (matrix and
    vectors) come back apart, an adapter cost no code pays natively.

    Parameters
    ----------
    nx : int
        Voxels along x (nx/4 along y and z).
    nodes : (n, 3) float
        The peer's node positions, m.
    node_dofs : (n, 3) int
        The peer's DOF of each node's x, y, z component.
    peer_free : (F,) int
        The peer's free DOFs, in the order of its free-DOF matrix.
    """

    def __init__(self, nx, nodes, node_dofs, peer_free):
        from voxflex.deform.materials.constitutive import material
        from voxflex.deform.models.voxel.model import VoxelModel

        model = VoxelModel.from_image(_beam_image(nx), {1: material("hooke", young=1e4, poisson=0.3, strain="linear")})
        self.model = model
        self.grid = model.grid
        self.free = np.flatnonzero(np.repeat(model.rest[:, 0] > 1e-9, 3))
        dims = np.array([nx, nx // 4, nx // 4]) + 1
        h = np.array([4.0, 1.0, 1.0]) / (dims - 1)

        def index(X):
            ijk = np.rint(np.asarray(X) / h).astype(np.int64)
            assert np.allclose(ijk * h, X, atol=1e-9 * h.min()), "a node off the voxel grid"
            return np.ravel_multi_index(ijk.T, dims)

        vox_node = np.full(int(np.prod(dims)), -1)
        vox_node[index(model.rest)] = np.arange(model.n_nodes)
        match = vox_node[index(nodes)]
        assert len(nodes) == model.n_nodes and np.all(match >= 0), "the peer's nodes are not voxflex's"
        node_dofs = np.asarray(node_dofs)
        vox_dof = np.empty(3 * model.n_nodes, dtype=np.int64)  # peer DOF -> voxflex DOF
        vox_dof[node_dofs.ravel()] = (3 * match[:, None] + np.arange(3)).ravel()
        pos = np.full(3 * model.n_nodes, -1)
        pos[vox_dof[np.asarray(peer_free)]] = np.arange(len(peer_free))
        self.q = pos[self.free]
        assert len(peer_free) == len(self.free) and np.all(self.q >= 0), "the peer clamps other DOFs than voxflex"
        self.keep = False  # remember the last reordered matrix (the self-check)
        self.last = None

    def solve(self, A, b, rtol):
        """``x`` of ``A x = b`` (peer order) by multigrid-CG in voxflex's order; info; reordering seconds.

        Asserts that ``A x = b`` to the solver's reported relative residual
        (times 1 + 1e-6, round-off of the two orders' sums) after reordering back.
        """
        from voxflex.deform.solve.linear import solve_linear

        t = time.perf_counter()
        Aq = A[self.q][:, self.q]
        bq = b[self.q]
        adapt = time.perf_counter() - t
        y, info = solve_linear(Aq, bq, method="multigrid", rtol=rtol, grid=self.grid, free=self.free)
        t = time.perf_counter()
        x = np.empty_like(y)
        x[self.q] = y
        adapt += time.perf_counter() - t
        res = np.linalg.norm(A @ x - b) / np.linalg.norm(b)
        assert res <= max(rtol, info.residual) * (1 + 1e-6), f"reordered solve: residual {res:.2e} in the peer's order"
        if self.keep:
            self.last = Aq
        return x, info, adapt


_ORDERS = {}  # (code, nx) -> VoxelOrder


def voxel_order(code, nx):
    """The cached :class:`VoxelOrder` of ``code`` ("scikit-fem" or "warp.fem") at ``nx``."""
    if (code, nx) not in _ORDERS:
        if code == "scikit-fem":
            from skfem import Basis, ElementHex1, ElementVector, MeshHex

            ny = nz = nx // 4
            mesh = MeshHex.init_tensor(np.linspace(0, 4, nx + 1), np.linspace(0, 1, ny + 1),
                                       np.linspace(0, 1, nz + 1))
            basis = Basis(mesh, ElementVector(ElementHex1()), intorder=3)
            D = basis.get_dofs(lambda x: x[0] < 1e-9).all()
            _ORDERS[code, nx] = VoxelOrder(nx, mesh.p.T, basis.nodal_dofs.T, np.setdiff1d(np.arange(basis.N), D))
        else:
            from _warp_cantilever import node_positions

            X = node_positions(nx)
            dofs = 3 * np.arange(len(X))[:, None] + np.arange(3)
            _ORDERS[code, nx] = VoxelOrder(nx, X, dofs, np.flatnonzero(np.repeat(X[:, 0] >= 1e-9, 3)))
    return _ORDERS[code, nx]


def check_order(code, run):
    """Self-check of a peer's :class:`VoxelOrder` on the 8x2x2 beam: its reordered linear stiffness is
    voxflex's free-DOF stiffness block (the same trilinear hexahedra and 2x2x2 Gauss points) to 1e-12
    relative (round-off of different summation orders; a wrong node match would differ by O(1))."""
    order = voxel_order(code, 8)
    order.keep = True
    run()
    order.keep = False
    K = order.model.constant_stiffness_block(order.free)
    err = abs(order.last - K).max() / abs(K).max()
    assert err <= 1e-12, f"{code}: the reordered stiffness differs from voxflex's by {err:.1e} (relative)"
    order.last = None
    return err


def newton_rtol(rn, rhs_norm, scale, tol=1e-8):
    """voxflex's inexact-Newton tolerance of a Newton solve (its forcing term ``min(0.1, |r| / scale)``,
    no tighter than the Newton tolerance needs), for the peers' multigrid-CG Neo-Hooke runs."""
    from voxflex.deform.solve.newton import _forcing

    eta = max(_forcing(rn, None, None, scale), 0.5 * tol * scale / max(rhs_norm, 1e-300))
    return float(np.clip(eta, 1e-14, 0.5))


SHARED_SOLVERS = ("cg", "direct", "multigrid")
"""Solvers of the same-solver table: Jacobi-CG (linear beam), sparse LU (Neo-Hooke), multigrid-CG (both)."""


def _free_solver(code):
    """``free_solver`` for ``warp_run``: nx -> the reordered multigrid-CG solve of ``code`` at nx, a
    fresh hierarchy for each run (``clear_cache`` as voxflex's runs)."""
    from voxflex.deform.solve.multigrid import hierarchy as multigrid

    def make(nx):
        multigrid.clear_cache()
        return voxel_order(code, nx).solve

    return make


def _summary(runs):
    """The fastest of a code's runs, with total = its min, total_median and CPU min / median."""
    import statistics

    best = min(runs, key=lambda r: r["total"])
    best["total_median"] = statistics.median(r["total"] for r in runs)
    best["cpu_min"] = min(r["cpu"] for r in runs)
    best["cpu_median"] = statistics.median(r["cpu"] for r in runs)
    return best


def _once(fn):
    c = time.process_time()
    r = fn()
    # CPU seconds of the call (all threads of this process), less a warm-up it ran (warp's compile)
    r["cpu"] = time.process_time() - c - r.get("compile_cpu", 0.0)
    r["total"] = r["build"] + r["assemble"] + r["solve"]
    return r


SETTLE_S = 0.5
"""Pause before each timed run of :func:`_interleaved`: warp.fem's threads stay busy for 0.1-0.2 s
after its call returns, and were charged to the CPU seconds of the code timed next (voxflex's linear
multigrid run measured 0.39-0.51 CPU s for 0.26-0.39 s wall right after warp.fem, 0.41 for 0.41 after
a 0.5 s pause)."""


def _interleaved(fns, n):
    """Run every code's ``fn`` n times, round-robin (code A, B, C, A, B, C, ...), so that a slow spell of
    a shared machine falls on every code alike instead of on one code's back-to-back repeats (the host's
    speed moved 2x within minutes: the same Jacobi-CG solve took 1.0 to 2.8 s), each after a pause of
    :data:`SETTLE_S`.  Returns {code: summary}."""
    runs = {code: [] for code in fns}
    for _ in range(n):
        for code, fn in fns.items():
            time.sleep(SETTLE_S)
            runs[code].append(_once(fn))
    return {code: _summary(r) for code, r in runs.items()}


def _repeat(fn, n):
    """Run ``fn`` n times back to back (the scaling series: one code); its summary."""
    return _summary([_once(fn) for _ in range(n)])


def voxflex_linear(nx, mat, linear_solver):
    """One linear static solve, timed like the peers: the free-DOF stiffness block, ``solve_linear``.

    The block comes from ``VoxelModel.constant_stiffness_block`` (what
    ``voxflex.deform.solve.stepping.solve`` takes for constant-tangent static problems):
    its time is the "assemble" column (the peers' condensation is in their "solve").
    """
    from voxflex.deform.models.voxel.model import VoxelModel
    from voxflex.deform.solve.linear import solve_linear
    from voxflex.deform.solve.multigrid import hierarchy as multigrid

    multigrid.clear_cache()  # every repeat builds its hierarchy (no reuse across timed runs)
    t0 = time.perf_counter()
    model = VoxelModel.from_image(_beam_image(nx), {1: mat})
    free = np.flatnonzero(np.repeat(model.rest[:, 0] > 1e-9, 3))
    t1 = time.perf_counter()
    A = model.constant_stiffness_block(free)
    f = model.gravity_force({1: 1.0}, [0, 0, -9.81]).ravel()
    t2 = time.perf_counter()
    # what solve() passes on its lean path: the block's matrix as voxel element matrices (multigrid forms
    # its first coarse level from them; the same level as the peers' sparse product, to round-off)
    x, info = solve_linear(A, f[free], method=linear_solver, rtol=1e-8, grid=model.grid, free=free,
                           elements=model.stiffness_elements())
    u = np.zeros(3 * model.n_nodes)
    u[free] = x
    t3 = time.perf_counter()
    uz = float(model.point_mapping([TIP]).apply(model.rest + u.reshape(-1, 3))[0, 2] - TIP[2])
    return dict(build=t1 - t0, assemble=t2 - t1, solve=t3 - t2, uz=uz, newton=1, linear=info.iterations,
                solver=info.method, fallbacks=int(info.fell_back))


def voxflex_run(nx, mat, steps, linear_solver):
    from voxflex.deform.models.voxel.model import VoxelModel
    from voxflex.deform.solve.boundary import FixedRegion
    from voxflex.deform.solve.multigrid import hierarchy as multigrid
    from voxflex.deform.solve.options import SolverOptions
    from voxflex.deform.solve.stepping import solve

    multigrid.clear_cache()  # every repeat builds its hierarchy (no reuse across timed runs)
    notes = []
    t0 = time.perf_counter()
    model = VoxelModel.from_image(_beam_image(nx), {1: mat})
    model._ensure_pattern()
    t1 = time.perf_counter()
    # one assembly, timed alone; a constant stiffness is cached by the model, so the solve reuses it
    # (a nonlinear material reassembles at every Newton iteration, inside "solve")
    model.energy_gradient_hessian(model.rest)
    t2 = time.perf_counter()
    rec = solve(model, fixed=[FixedRegion([-1, -1, -1], [1e-9, 2, 2])], gravity=[0, 0, -9.81], densities={1: 1.0},
                options=SolverOptions(steps=steps, linear_solver=linear_solver),
                newton_callback=lambda d: notes.append(d["linear_solver"]))
    t3 = time.perf_counter()
    uz = float(model.point_mapping([TIP]).apply(rec[-1].q)[0, 2] - TIP[2])
    its = sum(r.newton_iterations for r in rec)
    lin = sum(r.linear_iterations for r in rec)
    return dict(build=t1 - t0, assemble=t2 - t1, solve=t3 - t2, uz=uz, newton=its, linear=lin,
                solver=rec[-1].linear_solver.split(" (")[0], fallbacks=sum("fell back" in n for n in notes))


def skfem_run(nx, young, poisson, kind, steps, linear_solver, forcing=False):
    """The cantilever in scikit-fem, timed like the others; ``forcing``: Newton solves at voxflex's
    inexact-Newton tolerance (:func:`newton_rtol`) instead of rtol 1e-8."""
    from skfem import (
        Basis,
        BilinearForm,
        ElementHex1,
        ElementVector,
        LinearForm,
        MeshHex,
        condense,
    )
    from skfem.helpers import ddot, det, grad, inv, sym_grad, trace, transpose

    from voxflex.deform.solve.linear import solve_linear
    from voxflex.deform.solve.multigrid import hierarchy as multigrid

    order = None
    if linear_solver == "multigrid":  # voxflex's multigrid-CG on the reordered system (see VoxelOrder)
        order = voxel_order("scikit-fem", nx)
        multigrid.clear_cache()  # every run builds its own hierarchy, as voxflex's runs do
    t_adapt = 0.0
    lin_its = 0
    fallbacks = 0

    def free_solve(A, b, rtol):
        nonlocal t_adapt, lin_its, fallbacks
        if order is None:
            x, info = solve_linear(A, b, method=linear_solver, rtol=rtol)
        else:
            x, info, adapt = order.solve(A, b, rtol)
            t_adapt += adapt
        lin_its += info.iterations
        fallbacks += info.fell_back
        return x

    mu = young / (2 * (1 + poisson))
    lam = young * poisson / ((1 + poisson) * (1 - 2 * poisson))
    t0 = time.perf_counter()
    ny = nz = nx // 4
    mesh = MeshHex.init_tensor(np.linspace(0, 4, nx + 1), np.linspace(0, 1, ny + 1), np.linspace(0, 1, nz + 1))
    basis = Basis(mesh, ElementVector(ElementHex1()), intorder=3)
    D = basis.get_dofs(lambda x: x[0] < 1e-9).all()
    node = int(np.flatnonzero(np.all(np.isclose(mesh.p.T, TIP), axis=1))[0])
    t1 = time.perf_counter()

    @LinearForm
    def gravity(v, w):
        return -9.81 * v[2]

    def mm(a, b):
        return np.einsum("ij...,jk...->ik...", a, b)

    def kin(w):
        F = grad(w["u"]).copy()
        for i in range(3):
            F[i, i] += 1.0
        FinvT = transpose(inv(F))
        return F, FinvT, np.log(det(F))

    @BilinearForm
    def linear(u, v, w):
        e = sym_grad(u)
        return 2 * mu * ddot(e, sym_grad(v)) + lam * trace(e) * trace(sym_grad(v))

    @LinearForm
    def internal(v, w):
        F, FinvT, L = kin(w)
        return ddot(mu * (F - FinvT) + lam * L * FinvT, grad(v))

    @BilinearForm
    def tangent(du, v, w):
        F, FinvT, L = kin(w)
        dF = grad(du)
        return ddot(mu * dF + (mu - lam * L) * mm(mm(FinvT, transpose(dF)), FinvT) + lam * ddot(FinvT, dF) * FinvT,
                    grad(v))

    fg = gravity.assemble(basis)
    t_asm = 0.0
    t_sol = 0.0
    newton = 0
    u = np.zeros(basis.N)
    if kind == "linear":
        ta = time.perf_counter()
        K = linear.assemble(basis)
        t_asm += time.perf_counter() - ta
        ts = time.perf_counter()
        A, b, x, I = condense(K, fg, D=D)
        u[I] = free_solve(A, b, 1e-8)
        t_sol += time.perf_counter() - ts
        newton = 1
    else:
        for k in range(1, steps + 1):
            for _ in range(50):
                ta = time.perf_counter()
                uf = basis.interpolate(u)
                r = internal.assemble(basis, u=uf) - k / steps * fg
                r[D] = 0
                t_asm += time.perf_counter() - ta
                if np.linalg.norm(r) <= 1e-8 * np.linalg.norm(fg):
                    break
                ta = time.perf_counter()
                K = tangent.assemble(basis, u=uf)
                t_asm += time.perf_counter() - ta
                ts = time.perf_counter()
                A, b, x, I = condense(K, -r, D=D)
                rn = np.linalg.norm(r)
                u[I] += free_solve(A, b, newton_rtol(rn, rn, np.linalg.norm(fg)) if forcing else 1e-8)
                t_sol += time.perf_counter() - ts
                newton += 1
    uz = float(u[basis.nodal_dofs[2, node]])
    return dict(build=t1 - t0, assemble=t_asm, solve=t_sol - t_adapt, uz=uz, newton=newton, linear=lin_its,
                solver=linear_solver, permute=t_adapt, fallbacks=fallbacks)


def solver_table(nx):
    from voxflex.deform.chain.rigid_modes import rigid_body_modes
    from voxflex.deform.materials.constitutive import material
    from voxflex.deform.models.voxel.model import VoxelModel
    from voxflex.deform.solve.linear import solve_linear

    model = VoxelModel.from_image(_beam_image(nx), {1: material("hooke", young=1e4, poisson=0.3, strain="linear")})
    K = model.hessian(model.rest)
    free = np.flatnonzero(np.repeat(model.rest[:, 0] > 1e-9, 3))
    A = K[free][:, free]
    b = -model.gravity_force({1: 1.0}, [0, 0, -9.81]).ravel()[free]
    rows = []
    for method in ("cg", "multigrid", "amg", "direct"):
        x, info = solve_linear(A, b, method=method, rtol=1e-8, near_null=rigid_body_modes(model.rest)[free],
                               grid=model.grid, free=free)
        rows.append((method, info.seconds, info.iterations, info.residual))
    return len(free), rows


def memory_run(shape, linear_solver="cg"):
    """Peak resident memory after each phase of the linear beam of ``shape`` voxels (fresh process).

    Through ``voxflex.deform.solve.stepping.solve`` with ``linear_solver``: its lean
    path for constant-tangent static problems (the free-DOF block assembled
    and compacted in place, gradients matrix-free).
    """
    import resource

    from voxflex.deform.materials.constitutive import material
    from voxflex.deform.models.voxel.model import VoxelModel
    from voxflex.deform.solve.boundary import FixedRegion
    from voxflex.deform.solve.options import SolverOptions
    from voxflex.deform.solve.stepping import solve
    from voxflex.image.label_image import LabelImage

    def peak():
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB -> MB on Linux

    nx, ny, nz = shape
    rows = [("start (python, numpy, scipy, numba imported)", 0.0, peak())]
    t_all = time.perf_counter()
    t = time.perf_counter()
    image = LabelImage(np.ones((nx, ny, nz), dtype=np.uint8), spacing=(4 / nx, 1 / ny, 1 / nz))
    model = VoxelModel.from_image(image, {1: material("hooke", young=1e4, poisson=0.3, strain="linear")})
    rows.append(("image + model", time.perf_counter() - t, peak()))
    ndof = 3 * model.n_nodes
    # the product path: solve() takes the lean free block for this constant-tangent static problem
    # (assembled on its own and compacted in place; no full stiffness built or cached)
    t = time.perf_counter()
    rec = solve(model, fixed=[FixedRegion([-1, -1, -1], [1e-9, 2, 2])], gravity=[0, 0, -9.81],
                densities={1: 1.0}, options=SolverOptions(linear_solver=linear_solver))
    rows.append((f"static solve (solve(), {rec[-1].linear_solver}, {rec[-1].linear_iterations} iterations)",
                 time.perf_counter() - t, peak()))
    assert model._constant is None, "the lean path cached a stiffness"
    u = rec[-1].q - model.rest
    # check: the reactions (matrix-free gradient K u at the fixed DOFs) carry the weight of the free nodes
    # (K annihilates translations: sum_fixed (K u)_z = -sum_free (K u)_z = -sum_free f_z)
    t = time.perf_counter()
    g = model.gradient(model.rest + u).ravel()
    fixed = np.repeat(model.rest[:, 0] <= 1e-9, 3)
    weight = -float(model.gravity_force({1: 1.0}, [0, 0, -9.81])[~fixed[::3], 2].sum())
    reaction_z = float(g[fixed].reshape(-1, 3)[:, 2].sum())
    uz = float(model.point_mapping([TIP]).apply(model.rest + u)[0, 2] - TIP[2])
    rows.append((f"check: reaction z {reaction_z:.6f} N (load on the free nodes {weight:.6f} N), tip u_z {uz:.6f} m",
                 time.perf_counter() - t, peak()))
    total = time.perf_counter() - t_all
    print(f"\n| linear beam {nx}x{ny}x{nz}: {model.n_elements} voxels, {ndof} DOF | seconds | peak RSS MB |")
    print("|---|---|---|")
    for name, sec, mb in rows:
        print(f"| {name} | {sec:.2f} | {mb:.0f} |", flush=True)
    print(f"| total | {total:.2f} | {rows[-1][2]:.0f} ({rows[-1][2] * 2**20 / ndof:.0f} bytes/DOF at peak) |")


BIG_BYTES_PER_DOF = 1000
"""Peak bytes per DOF of the lean multigrid path through ``voxflex simulate``, measured at 256x90x90
(964; 666 through ``solve()``): the --big estimate."""


CLI_SCENE = """title = "linear beam {nx}x{ny}x{nz} (bench_voxel_model.py --cli)"
[object]
shape = "box"
size = [{sx!r}, {sy!r}, {sz!r}]
voxel_size = {h!r}
[[material]]
model = "hooke"
young = 1.0e4
poisson = 0.3
density = 1.0
strain = "linear"
[nodes]
kind = "voxel"
[[fixed]]
max = [1e-9, 1e9, 1e9]
[[load]]
kind = "gravity"
vector = [0.0, 0.0, -9.81]
[solver]
linear_solver = "{solver}"
"""


def cli_run(shape, linear_solver="multigrid"):
    """The linear beam of ``shape`` voxels (cubes of edge 1 / ny... along x: 4 / nx) as a scene through
    ``voxflex simulate`` in a fresh process: its wall time, the solve's share (--verbose) and peak RSS."""
    import re
    import resource
    import subprocess
    import sys
    import tempfile

    nx, ny, nz = shape
    h = 4.0 / nx
    text = CLI_SCENE.format(nx=nx, ny=ny, nz=nz, sx=nx * h, sy=ny * h, sz=nz * h, h=h, solver=linear_solver)
    with tempfile.TemporaryDirectory() as tmp:
        scene = os.path.join(tmp, "beam.toml")
        with open(scene, "w") as fh:
            fh.write(text)
        t = time.perf_counter()
        r = subprocess.run([sys.executable, "-m", "voxflex", "simulate", scene, "-o", os.path.join(tmp, "beam.h5"),
                            "--verbose"], capture_output=True, text=True)
        wall = time.perf_counter() - t
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024
    dofs = re.search(r"model: \d+ voxel nodes, (\d+) DOF", r.stderr)
    newton = re.findall(r"Newton (\d+): .*?, ([0-9.]+) s$", r.stderr, flags=re.M)
    built = re.search(r"model built in ([0-9.]+) s", r.stderr)
    if r.returncode != 0 or dofs is None:
        print(r.stdout[-2000:], r.stderr[-2000:])
        return
    ndof = int(dofs.group(1))
    solve_s = sum(float(sec) for _, sec in newton)
    print(f"\n| linear beam {nx}x{ny}x{nz} through voxflex simulate ({ndof} DOF) | value |")
    print("|---|---|")
    print(f"| wall time of the command | {wall:.1f} s |")
    print(f"| model built | {float(built.group(1)):.1f} s |" if built else "| model built | ? |")
    print(f"| Newton iterations (solve, gradients, line search) | {solve_s:.1f} s |")
    print(f"| peak RSS | {peak / 2**20:.0f} MB = {peak / ndof:.0f} bytes/DOF |")
    print(r.stdout.strip().replace("\n", " / "))


def _load():
    """The load averages (1, 5, 15 min): other work on a shared machine inflates wall times."""
    try:
        return "load average {:.2f} {:.2f} {:.2f}".format(*os.getloadavg())
    except OSError:
        return "load average unknown"


def _available_bytes():
    """MemAvailable of /proc/meminfo in bytes (None where there is none)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None


def scaling_series(sizes, repeat):
    """Linear beam solves at growing sizes: multigrid-CG and Jacobi-CG, time, iterations, traced peak memory."""
    import statistics
    import tracemalloc

    from voxflex.deform.materials.constitutive import material
    from voxflex.deform.models.voxel.model import VoxelModel
    from voxflex.deform.solve.linear import solve_linear
    from voxflex.deform.solve.multigrid import hierarchy as multigrid

    hooke = material("hooke", young=1e4, poisson=0.3, strain="linear")
    print("\n| beam | DOF | solver | solve s (min / median) | iterations | peak traced MB | bytes/DOF |")
    print("|---|---|---|---|---|---|---|")
    fits = {}
    for nx in sizes:
        model = VoxelModel.from_image(_beam_image(nx), {1: hooke})
        K = model.hessian(model.rest)
        free = np.flatnonzero(np.repeat(model.rest[:, 0] > 1e-9, 3))
        A = K[free][:, free]
        b = -model.gravity_force({1: 1.0}, [0, 0, -9.81]).ravel()[free]
        del K
        for method in ("multigrid", "cg"):
            times = []
            for _ in range(repeat):
                multigrid.clear_cache()  # a fresh hierarchy each time (a first Newton iteration)
                t = time.perf_counter()
                _, info = solve_linear(A, b, method=method, rtol=1e-8, grid=model.grid, free=free)
                times.append(time.perf_counter() - t)
            multigrid.clear_cache()
            tracemalloc.start()
            solve_linear(A, b, method=method, rtol=1e-8, grid=model.grid, free=free)
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
            fits.setdefault(method, []).append((len(free), min(times)))
            print(f"| {nx}x{nx // 4}x{nx // 4} | {len(free)} | {info.method} | {min(times):.3f} / "
                  f"{statistics.median(times):.3f} | {info.iterations} | {peak / 2**20:.0f} | "
                  f"{peak / len(free):.0f} |", flush=True)
    for method, pts in fits.items():
        n, t = np.array(pts).T
        big = n >= 5000  # below, fixed costs dominate
        if big.sum() >= 2:
            p = np.polyfit(np.log(n[big]), np.log(t[big]), 1)[0]
            print(f"{method}: solve time ~ DOF^{p:.2f} (least squares over the sizes with >= 5000 DOF)")
    print("peak traced memory: the solver's own arrays (hierarchy, levels, CG vectors) beyond the given matrix")


PLATE_SOLVERS = ("auto", "direct", "cg")


def plate_run(solvers, repeat, n=64):
    """The one-voxel-thick neo-Hooke plate: n x n x 1 voxels of 1/n m, E = 1e5 Pa, nu = 0.45, density 1,
    the edge x = 0 clamped, gravity, 5 load steps; each solver warmed on a 16x16x1 plate, then timed
    ``repeat`` times round-robin (:func:`_interleaved`): total (model and solve) and CPU seconds, min /
    median, Newton and linear iterations and the largest sag.  Jacobi-CG takes minutes a run."""
    from voxflex.deform.materials.constitutive import material
    from voxflex.deform.models.voxel.model import VoxelModel
    from voxflex.deform.solve.boundary import FixedRegion
    from voxflex.deform.solve.options import SolverOptions
    from voxflex.deform.solve.stepping import solve
    from voxflex.image.label_image import LabelImage

    def run(m, solver):
        t0 = time.perf_counter()
        model = VoxelModel.from_image(LabelImage(np.ones((m, m, 1)), spacing=(1 / m,) * 3),
                                      {1: material("neo-hookean", young=1e5, poisson=0.45)})
        t1 = time.perf_counter()
        rec = solve(model, fixed=[FixedRegion([-1, -1, -1], [1e-9, 2, 2])], gravity=[0, 0, -9.81], densities={1: 1.0},
                    options=SolverOptions(steps=5, linear_solver=solver))
        t2 = time.perf_counter()
        return dict(build=t1 - t0, assemble=0.0, solve=t2 - t1, newton=sum(r.newton_iterations for r in rec),
                    linear=sum(r.linear_iterations for r in rec), sag=-float((rec[-1].q[:, 2] - model.rest[:, 2]).min()),
                    used=rec[-1].linear_solver, dof=3 * model.n_nodes)

    for solver in solvers:
        run(16, solver)  # warm the kernels of this path
    out = _interleaved({solver: (lambda solver=solver: run(n, solver)) for solver in solvers}, repeat)
    print(f"\nneo-Hooke plate {n}x{n}x1 (E = 1e5, nu = 0.45, 5 load steps), {repeat} runs each, round-robin")
    print("| linear solver | used | DOF | total s min / median | CPU s min / median | newton | linear its | max sag m |")
    print("|---|---|---|---|---|---|---|---|")
    for solver, r in out.items():
        print(f"| {solver} | {r['used']} | {r['dof']} | {r['total']:.1f} / {r['total_median']:.1f} | "
              f"{r['cpu_min']:.1f} / {r['cpu_median']:.1f} | {r['newton']} | {r['linear']} | {r['sag']:.4f} |")
    print(f"({_load()})")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--colamd", action="store_true")
    parser.add_argument("--memory", default="", metavar="NXxNYxNZ")
    parser.add_argument("--big", action="store_true")
    parser.add_argument("--cli", action="store_true",
                        help="run --big / --memory as a scene through voxflex simulate (a fresh process)")
    parser.add_argument("--solver", default="cg", choices=("cg", "multigrid", "direct"),
                        help="linear solver of --memory (--big always uses multigrid)")
    parser.add_argument("--no-series", action="store_true")
    parser.add_argument("--tables-only", action="store_true",
                        help="only the two peer tables (no solver table, no scaling series)")
    parser.add_argument("--shared-solvers", default=",".join(SHARED_SOLVERS), metavar="LIST",
                        help="solvers of the same-solver table, comma separated among "
                             f"{', '.join(SHARED_SOLVERS)} (cg: linear beam, direct: Neo-Hooke, multigrid: both)")
    parser.add_argument("--no-skfem", action="store_true", help="skip scikit-fem (~60 s per Neo-Hooke run)")
    parser.add_argument("--plate", nargs="?", const=",".join(PLATE_SOLVERS), default="", metavar="LIST",
                        help="only the 64x64x1 neo-Hooke plate, with each linear solver of LIST "
                             f"(default {','.join(PLATE_SOLVERS)}; cg takes minutes)")
    args = parser.parse_args()
    shared = [m.strip() for m in args.shared_solvers.split(",") if m.strip()]
    bad = [m for m in shared if m not in SHARED_SOLVERS]
    if bad:
        parser.error(f"--shared-solvers: unknown {', '.join(bad)}; choose among {', '.join(SHARED_SOLVERS)}")
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"python {platform.python_version()}, NUMBA_NUM_THREADS={os.environ.get('NUMBA_NUM_THREADS', 'default')}, "
          f"{_load()}")
    if args.plate:
        plate_run([m.strip() for m in args.plate.split(",") if m.strip()], args.repeat)
        return
    if args.memory:
        shape = tuple(int(v) for v in args.memory.lower().split("x"))
        cli_run(shape, args.solver) if args.cli else memory_run(shape, args.solver)
        return
    if args.big:
        need = BIG_BYTES_PER_DOF * 3 * 257 * 91 * 91
        avail = _available_bytes()
        if avail is not None and avail < 1.3 * need:
            print(f"--big refused: {avail / 2**30:.1f} GiB available, under 1.3 x the {need / 2**30:.1f} GiB estimate")
            return
        cli_run((256, 90, 90), "multigrid") if args.cli else memory_run((256, 90, 90), "multigrid")
        return
    from voxflex.deform.materials.constitutive import material

    nl, nn = (32, 16) if args.quick else (64, 32)
    hooke = material("hooke", young=1e4, poisson=0.3, strain="linear")
    nh = material("neo-hookean", young=1e3, poisson=0.3)
    try:  # optional peer: warp.fem on the CPU (compiles its kernels once, timed apart)
        from _warp_cantilever import warp_run
    except ImportError:
        warp_run = None
        print("warp.fem: not installed (pip install warp-lang) - its rows are skipped")
    # warm-up of every code on an 8x2x2 beam: numba kernels, scikit-fem's forms, warp's compile
    voxflex_run(8, nh, 1, "direct")
    voxflex_run(8, nh, 1, "multigrid")
    voxflex_linear(8, hooke, "cg")
    voxflex_linear(8, hooke, "multigrid")
    if not args.no_skfem:
        skfem_run(8, 1e4, 0.3, "linear", 1, "cg")
        skfem_run(8, 1e3, 0.3, "neo-hooke", 1, "direct")
    checks = []
    if "multigrid" in shared:
        # the peers' reorderings, built once per size before any timing, and checked on the 8x2x2 beam
        if not args.no_skfem:
            checks.append(("scikit-fem", check_order("scikit-fem", lambda: skfem_run(8, 1e4, 0.3, "linear", 1,
                                                                                     "multigrid"))))
            skfem_run(8, 1e3, 0.3, "neo-hooke", 1, "multigrid", forcing=True)
        if warp_run:
            checks.append(("warp.fem", check_order("warp.fem", lambda: warp_run(
                8, 1e4, 0.3, "linear", 1, "multigrid", warmup=False, free_solver=_free_solver("warp.fem")))))
        for code in [c for c, _ in checks]:
            voxel_order(code, nl)
            voxel_order(code, nn)
    lin, neo = f"linear {nl}x{nl // 4}x{nl // 4}", f"neo-hooke E=1e3 {nn}x{nn // 4}x{nn // 4} 5 steps"

    def peers(nx, kind, steps, solver):
        young = 1e4 if kind == "linear" else 1e3
        mg = solver == "multigrid"
        forcing = mg and kind != "linear"  # Newton solves at voxflex's inexact-Newton tolerance
        out = []
        if not args.no_skfem:
            out.append(("scikit-fem", solver, lambda: skfem_run(nx, young, 0.3, kind, steps, solver, forcing=forcing)))
        if warp_run:
            out.append(("warp.fem", solver, lambda: warp_run(nx, young, 0.3, kind, steps, solver,
                                                     free_solver=_free_solver("warp.fem") if mg else None,
                                                     newton_rtol=newton_rtol if forcing else None)))
        return out

    same = []
    if "cg" in shared:
        same.append((f"{lin} | Jacobi-CG", [("voxflex", "cg", lambda: voxflex_linear(nl, hooke, "cg"))]
                     + peers(nl, "linear", 1, "cg")))
    if "multigrid" in shared:
        same.append((f"{lin} | multigrid-CG", [("voxflex", "multigrid", lambda: voxflex_linear(nl, hooke, "multigrid"))]
                     + peers(nl, "linear", 1, "multigrid")))
    if "direct" in shared:
        same.append((f"{neo} | sparse LU", [("voxflex", "direct", lambda: voxflex_run(nn, nh, 5, "direct"))]
                     + peers(nn, "neo-hooke", 5, "direct")))
    if "multigrid" in shared:
        same.append((f"{neo} | multigrid-CG",
                     [("voxflex", "multigrid", lambda: voxflex_run(nn, nh, 5, "multigrid"))]
                     + peers(nn, "neo-hooke", 5, "multigrid")))
    tables = [
        ("same solver for all codes (Jacobi-CG rtol 1e-8 / sparse LU MMD / multigrid-CG on voxflex's grid, the "
         "peers' matrices reordered to voxflex's DOF order: permute s, not in total)", same),
        ("best solver each (voxflex: multigrid-CG / auto; peers: Jacobi-CG / LU)", [
            (f"{lin} | best each", [("voxflex", "multigrid", lambda: voxflex_linear(nl, hooke, "multigrid"))]
             + peers(nl, "linear", 1, "cg")),
            (f"{neo} | best each", [("voxflex", "auto", lambda: voxflex_run(nn, nh, 5, "auto"))]
             + peers(nn, "neo-hooke", 5, "direct")),
        ]),
    ]
    for code, err in checks:
        print(f"{code}: reordered 8x2x2 stiffness = voxflex's to {err:.1e} (relative)")
    compile_notes = []
    done = {}  # (code, problem, solver) -> result: a peer's runs serve both tables (its solver is the same)
    for title, problems in tables:
        print(f"\n{title}; {args.repeat} runs each, the columns of the fastest run")
        print("| problem | solver | code | build s | assemble s | solve s | permute s | total s min / median "
              "| CPU s min / median | newton | linear its | fallbacks | u_z tip | solver used |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
        for label, codes in problems:
            name, solver_name = label.split(" | ")
            res = {}
            fresh = _interleaved({code: fn for code, code_solver, fn in codes if (code, name, code_solver) not in done},
                                 args.repeat)
            for code, code_solver, fn in codes:
                key = (code, name, code_solver)  # the same run serves every row that asks for it
                reused = key in done
                r = done[key] if reused else fresh[code]
                done[key] = r
                res[code] = r
                if reused:
                    code = f"{code} (the runs above)"
                elif "compile" in r:
                    compile_notes.append(f"{code} {name} {code_solver}: kernel compile/warm-up {r['compile']:.2f} s "
                                         "(not in total)")
                permute = f"{r['permute']:.2f}" if r.get("permute") else ""
                print(f"| {name} | {solver_name} | {code} | {r['build']:.2f} | {r['assemble']:.2f} | "
                      f"{r['solve']:.2f} | {permute} | {r['total']:.2f} / {r['total_median']:.2f} | "
                      f"{r['cpu_min']:.2f} / {r['cpu_median']:.2f} | {r['newton']} | {r['linear']} | "
                      f"{r.get('fallbacks', 0)} | {r['uz']:.6f} | {r['solver']} |", flush=True)
            for peer in [c for c, _, _ in codes[1:]]:
                a, b = res[peer], res["voxflex"]
                print(f"| {name} | {solver_name} | ratio {peer} / voxflex (min; median) | | | | | "
                      f"{a['total'] / b['total']:.2f}x; {a['total_median'] / b['total_median']:.2f}x | "
                      f"{a['cpu_min'] / b['cpu_min']:.2f}x; {a['cpu_median'] / b['cpu_median']:.2f}x | | | | | |",
                      flush=True)
            print(f"({_load()} after this problem)", flush=True)
    for note in compile_notes:
        print(note)
    if args.tables_only:
        return
    n, rows = solver_table(nl)
    print(f"\n| linear solver on the {n}-DOF clamped beam stiffness | seconds | iterations | relative residual |")
    print("|---|---|---|---|")
    for method, sec, its, res in rows:
        print(f"| {method} | {sec:.2f} | {its} | {res:.1e} |", flush=True)
    if not args.no_series:
        scaling_series((16, 32, 64) if args.quick else (16, 32, 64, 128), args.repeat)
    if args.colamd:
        import time as _t

        import scipy.sparse as sp
        import scipy.sparse.linalg as spla

        from voxflex.deform.materials.constitutive import material as _m
        from voxflex.deform.models.voxel.model import VoxelModel

        model = VoxelModel.from_image(_beam_image(nl), {1: _m("hooke", young=1e4, poisson=0.3, strain="linear")})
        free = np.flatnonzero(np.repeat(model.rest[:, 0] > 1e-9, 3))
        A = sp.csc_matrix(model.hessian(model.rest)[free][:, free])
        t = _t.perf_counter()
        spla.splu(A).solve(np.ones(len(free)))
        print(f"| splu default (COLAMD) | {_t.perf_counter() - t:.2f} | 0 | |")


if __name__ == "__main__":
    main()
