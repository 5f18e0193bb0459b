"""Geometric multigrid for the voxel model, used as the CG preconditioner.

The levels are voxel grids: level ``l + 1`` coarsens the occupancy image of
level ``l`` by 2 along every axis longer than one voxel, and a coarse voxel is
material when any of its (up to 8) fine voxels is, so that one-voxel-thin
parts stay connected on every level.  The nodes of a level are the corners of
its occupied voxels (as in :class:`~voxflex.image.grid.TrilinearGrid`).
The prolongation ``P`` maps coarse-node displacements to fine nodes by
trilinear interpolation inside the coarse voxel holding each fine node (the
coarse voxel of an occupied fine voxel touching it, so that voxel is
occupied), the same for each of the 3 components; it reproduces affine fields
exactly.  Fixed DOFs are handled by working on the free DOFs only: the rows of
``P`` at fixed fine DOFs are dropped, then the coarse DOFs whose column became
empty.  Coarse operators are Galerkin products ``P^T A P``.

Only the products depend on the matrix: the prolongations depend on the grid
and the free-DOF set, so :func:`hierarchy` caches them (one Newton solve after
another reuses them) and :meth:`VoxelHierarchy.solver` redoes just the
products.  The linear solver (``solve_linear(method="multigrid")``) goes
further: the next tangents of the same pattern are solved on the coarse levels
of an earlier one (the finest level, which smooths and forms the residuals, is
always the current matrix, and CG runs on it, so the answer meets its
tolerance whatever the coarse levels).  The levels are rebuilt after
:data:`MAX_STALE_SOLVES` such solves, after one that took more than
:data:`STALE_GROWTH` times the fresh levels' iterations, and at once when a
solve on them stalls or meets ``r . z <= 0`` (coarse levels far from the
current tangent can make the cycle indefinite); the solve then goes on from
where it was.  On the 32x8x8 neo-Hooke beam (31 Newton iterations) this took
129 CG iterations against 107 and 1.74-2.24 CPU s against 2.06-2.87 (3 runs
each, alternated); on the voxel default scene (F-bar, 22 Newton iterations)
1.72-2.11 s against 1.98-2.71; on the 64x64x1 neo-Hooke plate, where each solve
takes ~15 CG iterations and the products are cheap beside them, no change
(12.5-13.0 s against 12.5-12.7 s).

Three more things make a solve cheaper without changing the operators:

* a constant-tangent model passes its stiffness as voxel element matrices
  (:class:`ElementMatrices`, ``VoxelModel.stiffness_elements``), and the first
  coarse level is then summed from them (:meth:`VoxelHierarchy.first_level`)
  instead of formed by two sparse products: the same matrix to round-off, 5 ms
  against 60-180 ms at 55k DOF;
* with those element matrices the finest level is applied from the voxel
  stencil (:class:`VoxelStencil`): the rows of every node whose voxels share
  one material and volume and whose coupled neighbours are free (98 % of the
  rows of the 64x16x16 beam) come from a 3 x 81 stencil per pattern of voxels
  around the node instead of the stored matrix, the rest from the matrix.  The
  Gauss-Seidel sweeps keep the row order, so the cycle is the one on the
  assembled matrix (equal to 1e-15); at 55k DOF a sweep took 1.9 against 3.9
  ms, a product 1.6 against 4.5 ms, the whole solve 0.22 against 0.33 s (min
  of 6, alternated);
* the cycle runs in single precision (``precision="auto"``, up to
  :data:`SINGLE_MAX_ENTRIES` stored entries) while CG stays in double on A: a
  cycle at 55k DOF with the stored finest level took 16.5 against 21.6 ms
  (min of 40, alternated), the same 12 iterations.

The cycle, the smoothers (Gauss-Seidel by default, forward before
and backward after the coarse correction,
pointwise: component subsets of fixed DOFs break 3x3 nodal blocks, and pyamg's
3x3 block Gauss-Seidel took 4-7x longer for the same iteration count) and the
coarse solve are pyamg's :class:`pyamg.multilevel.MultilevelSolver`; the
coarsest system is factorised once per matrix by sparse LU
(:class:`~voxflex.deform.solve.multigrid.coarse._CoarseSolver`),
and the whole solve runs with BLAS pinned to one thread (threaded OpenBLAS
stalls on small dense work on a busy machine).

The coarsening and the prolongations between levels are in
:mod:`voxflex.deform.solve.multigrid.prolongation`, the Galerkin products and the
coarsest solve in :mod:`voxflex.deform.solve.multigrid.coarse`; this module stacks
them into the hierarchy, remembers its solvers and runs the cycle.

>>> import numpy as np
>>> from voxflex.image.label_image import LabelImage
>>> from voxflex.image.grid import TrilinearGrid
>>> grid = TrilinearGrid.from_image(LabelImage(np.ones((8, 2, 2))))
>>> h = hierarchy(grid, np.arange(3 * grid.n_nodes), max_coarse=40)
>>> [p.shape for p in h.prolongations], h.shapes
([(243, 60), (60, 36)], [(8, 2, 2), (4, 1, 1), (2, 1, 1)])

References
----------
Trottenberg, Oosterlee, Schueller, *Multigrid*, Academic Press 2001 (Galerkin
coarse operators, ch. 2-3); Dick, Georgii, Westermann, "A real-time multigrid
finite hexahedra method for elasticity simulation using CUDA", Simul. Model.
Pract. Theory 19 (2011) (hexahedral voxel hierarchies with "any"-occupancy
coarsening).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from ....errors import InputError, check_choice
from ....image.grid import CORNER_OFFSETS, TrilinearGrid
from .coarse import _CoarseSolver, _galerkin_impl
from .prolongation import (
    _child_transfers,
    _factors,
    dof_prolongation,
    node_prolongation,
)
from .stencil import (
    VoxelStencil,
    _coupled_offsets,
    _gather_forward,
    _unit_stencil,
    _voxel_keys,
)

SMOOTHERS = ("gauss-seidel", "symmetric-gauss-seidel", "jacobi")

PRECISIONS = ("auto", "single", "double")


MAX_COARSE = 1500
"""Coarsening stops once a level has at most this many free DOFs (factorised by sparse LU)..."""


MAX_COARSE_CUBIC = 300
"""...or this many (or 1/:data:`CUBIC_FRACTION` of the finest level's, if more), while the next level's
voxels would still be cubes (every axis longer than 1 voxel)."""


CUBIC_FRACTION = 32

MAX_LEVELS = 12


SINGLE_MAX_ENTRIES = 50_000_000
"""Fine matrices with at most this many stored entries get a single-precision cycle (see
:func:`multigrid_preconditioner`); larger ones keep double precision, since the single copy of
the finest matrix costs 4 bytes per entry (at 6.4 million DOF: 2 GB)."""


MAX_STALE_SOLVES = 3
"""Newton solves on coarse levels built from an earlier tangent before they are rebuilt (see
:meth:`VoxelHierarchy.may_reuse`)."""


STALE_GROWTH = 1.5
"""A solve on stale coarse levels that takes more than this times the fresh solve's CG iterations
(plus 2) has them rebuilt at the next solve."""


_CACHE_SIZE = 4


# -- the hierarchy -------------------------------------------------------------
@dataclass(eq=False)
class VoxelHierarchy:
    """Prolongations of a voxel grid's free DOFs down to a coarse level (depends on no matrix).

    Attributes
    ----------
    prolongations : list of (F_l, F_{l+1}) CSR
        Level l+1 to level l, free DOFs only; level 0 is the model's free DOFs.
    restrictions : list of (F_{l+1}, F_l) CSR
        Their transposes (kept in CSR for fast products).
    shapes : list of (3,) tuple
        Image shape of every level.
    free : (F,) int
        The fine free DOFs the hierarchy was built for.
    coarse_free : list of (F_{l+1},) int
        The DOFs (``3 * node + component`` of that level's nodes) kept on each coarser level.
    """

    prolongations: list
    restrictions: list
    shapes: list
    free: np.ndarray
    coarse_free: list
    geometry: list = field(default_factory=list, repr=False)
    """(element ijk, element nodes, node count, shape) of the finest two levels (see :meth:`first_level`)."""
    grid: TrilinearGrid | None = field(default=None, repr=False)
    """The finest level's grid (its node corner indices and keys serve :meth:`stencil`)."""
    _last: tuple | None = field(default=None, repr=False)
    _plan: tuple | None = field(default=None, repr=False)
    _single_pr: list | None = field(default=None, repr=False)
    fresh_iterations: int | None = field(default=None, repr=False)
    """CG iterations of the last solve on freshly built coarse levels (None: none reported)."""
    stale_solves: int = field(default=0, repr=False)
    """Solves on the remembered coarse levels since they were built."""
    refresh: bool = field(default=False, repr=False)
    """Rebuild the coarse levels at the next solve (a stale solve took too many iterations)."""

    @property
    def sizes(self) -> list:
        """Free DOFs per level, finest first."""
        return [len(self.free)] + [p.shape[1] for p in self.prolongations]

    def galerkin(self, A, elements=None) -> list:
        """The level matrices ``A_{l+1} = P_l^T A_l P_l`` (list of CSR, ``A`` first).

        With ``elements`` (A as a sum of voxel element matrices) the first
        coarse level is formed from them (:meth:`first_level`), the others by
        sparse products.
        """
        mats = [A if _matrix_free(A) else sp.csr_matrix(A)]
        for lvl, (P, R) in enumerate(zip(self.prolongations, self.restrictions)):
            if lvl == 0 and elements is not None:
                mats.append(self.first_level(elements))
            else:
                mats.append(_galerkin_impl(mats[-1], P, R))
        return mats

    def first_level(self, elements) -> sp.csr_matrix:
        """``P_0^T A P_0`` from the fine matrix's element matrices, without a sparse product.

        ``A = K[free][:, free]`` with ``K = sum_e scale_e units[kind_e]`` over
        the fine voxels (:class:`ElementMatrices`).  Every fine voxel lies in
        one coarse voxel, where the trilinear prolongation of its 8 corners is
        a fixed 24x24 matrix ``T_c`` for each of its 8 positions ``c``, so
        ``P^T A P = sum_e T_c^T (D_e K_e D_e) T_c`` assembled on the coarse
        voxels (``D_e`` zeroes the element's fixed DOFs).  For voxels without
        fixed DOFs that is ``sum_e scale_e U[kind_e, c_e]`` with the 8 products
        ``U = T_c^T units T_c`` computed once: a coarse voxel's matrix is a
        weighted sum of them.  Equal to the sparse product to round-off; on the
        64x16x16 beam (55k DOF) 5-9 ms against 60-180 ms.
        """
        from ...models.voxel._kernels import scatter_blocks

        if not self.prolongations:
            raise InputError("the hierarchy has a single level")
        plan = self._first_plan()
        parent, child, T, el_free, conn1, blockmap, indptr_b, n_data, sel, c_indptr, c_indices = plan
        units = np.asarray(elements.units, dtype=np.float64)
        kind = np.asarray(elements.kind)
        scale = np.asarray(elements.scale, dtype=np.float64)
        m = len(parent)
        if units.ndim != 3 or units.shape[1:] != (24, 24) or kind.shape != (m,) or scale.shape != (m,) or \
                (m and kind.max() >= len(units)):
            raise InputError(f"elements must hold (k, 24, 24) units and a kind (< k) and scale per voxel ({m} voxels)")
        used = kind >= 0
        whole = used & el_free.all(axis=1)
        nk = len(units)
        U = np.matmul(np.matmul(T.transpose(0, 2, 1)[None], units[:, None]), T[None]).reshape(8 * nk, 576)
        W = np.zeros((len(conn1), 8 * nk))
        np.add.at(W, (parent[whole], 8 * kind[whole] + child[whole]), scale[whole])
        data = np.zeros(n_data)
        step = 1024  # (step, 24, 24) blocks of 4.7 MB: 8192-row blocks (38 MB) cost 4-70 ms of page faults each
        for s0 in range(0, len(conn1), step):
            Kc = (W[s0 : s0 + step] @ U).reshape(-1, 24, 24)
            scatter_blocks(Kc, conn1[s0 : s0 + step], blockmap[s0 : s0 + step], indptr_b, data)
        part = np.flatnonzero(used & ~whole)  # voxels with fixed DOFs (a clamped face)
        for s0 in range(0, len(part), step):
            e = part[s0 : s0 + step]
            mask = el_free[e].astype(np.float64)
            Ke = units[kind[e]] * (scale[e][:, None, None] * mask[:, :, None] * mask[:, None, :])
            Tc = T[child[e]]
            Kc = np.matmul(np.matmul(Tc.transpose(0, 2, 1), Ke), Tc)
            scatter_blocks(Kc, conn1[parent[e]], blockmap[parent[e]], indptr_b, data)
        n = len(self.coarse_free[0])
        _gather_forward(data, sel)  # data[:k] = data[sel] in place (sel increases, sel[k] >= k)
        return sp.csr_matrix((data[: len(sel)], c_indices, c_indptr), shape=(n, n))

    def stencil(self, A, elements):
        """The finest level as a :class:`VoxelStencil` (interior nodes from the element matrices' stencil,
        the other rows from A), or None when no node qualifies."""
        ijk0, _, n0, shape0 = self.geometry[0]
        units = np.asarray(elements.units, dtype=np.float64)
        kind = np.asarray(elements.kind)
        scale = np.asarray(elements.scale, dtype=np.float64)
        shape = np.array(shape0)
        node_ijk = self.grid.node_ijk
        vox = np.full(int(np.prod(shape)), -1, dtype=np.int64)
        vox[_voxel_keys(ijk0, shape0)] = np.arange(len(ijk0))
        # per node, one pass per voxel v around it (the voxel at node - corner v): node-length temporaries
        pattern = np.zeros(n0, dtype=np.int64)  # bit v: that voxel exists
        k0 = np.full(n0, -1, dtype=np.int64)  # the material and volume of the first existing one
        s0 = np.zeros(n0)
        uniform = np.ones(n0, dtype=bool)  # all existing ones share them
        for v in range(8):
            vi = node_ijk - CORNER_OFFSETS[v]
            inside = np.all((vi >= 0) & (vi < shape), axis=1)
            ev = np.where(inside, vox[_voxel_keys(np.where(inside[:, None], vi, 0), shape0)], -1)
            here = ev >= 0
            ev[~here] = 0
            new = here & (pattern == 0)
            k0[new], s0[new] = kind[ev[new]], scale[ev[new]]
            uniform &= ~here | ((kind[ev] == k0) & (scale[ev] == s0))
            pattern |= here.astype(np.int64) << v
        uniform &= k0 >= 0
        pos = np.full(3 * n0, -1, dtype=np.int64)
        pos[self.free] = np.arange(len(self.free))
        node_free = (pos[0::3] >= 0) & (pos[1::3] >= 0) & (pos[2::3] >= 0)
        cshape = shape + 1
        table = np.full(int(np.prod(cshape)), -1, dtype=np.int64)  # node of a corner key (grid.node_key)
        table[self.grid.node_key] = np.arange(n0)
        nodes = np.flatnonzero(uniform & node_free)
        offsets = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)])
        key = self.grid.node_key[nodes]
        step = (offsets[:, 0] * cshape[1] + offsets[:, 1]) * cshape[2] + offsets[:, 2]
        idx = np.int32 if len(self.free) < np.iinfo(np.int32).max else np.int64
        nbr = np.empty((len(nodes), 27), dtype=idx)  # first free DOF of each neighbour
        ok = np.empty(len(nodes), dtype=bool)
        for c0 in range(0, len(nodes), 1 << 18):  # by blocks of nodes: (block, 27) temporaries
            blk = slice(c0, c0 + (1 << 18))
            coupled = _coupled_offsets()[pattern[nodes[blk]]]  # neighbours sharing a voxel of the pattern
            # coupled neighbours are corners of existing voxels, hence nodes; the others point at the node
            nb = table[key[blk, None] + np.where(coupled, step[None, :], 0)]
            ok[blk] = np.all(node_free[nb], axis=1)  # every coupled neighbour has its 3 DOFs free
            nbr[blk] = pos[3 * nb]
        nodes, nbr = nodes[ok], nbr[ok]
        if len(nodes) == 0:
            return None
        node_of_row = np.full(len(self.free), -1, dtype=idx)
        for c in range(3):
            node_of_row[pos[3 * nodes] + c] = np.arange(len(nodes))
        keys, stencil_id = np.unique(k0[nodes] * 256 + pattern[nodes], return_inverse=True)
        S = np.concatenate([_unit_stencil(units[key // 256], key % 256) for key in keys])  # (3 keys, 81)
        rows = np.flatnonzero(node_of_row < 0)
        if _matrix_free(A):  # no stored matrix: the other rows assembled from the element matrices
            return VoxelStencil(A, node_of_row, nbr, stencil_id.astype(np.int32), s0[nodes].copy(), S, rows,
                                stored=self._rows_from_elements(elements, rows))
        return VoxelStencil(sp.csr_matrix(A), node_of_row, nbr, stencil_id.astype(np.int32), s0[nodes].copy(), S,
                            rows)

    def _rows_from_elements(self, elements, rows):
        """Rows ``rows`` (sorted free-DOF indices) of ``K[free][:, free]`` assembled from the element matrices
        of the voxels around their nodes only: a (len(rows), F) CSR."""
        from ...._linalg import free_block
        from ...models.voxel._kernels import grid_block_pattern, scatter_blocks

        _, conn, n0, _ = self.geometry[0]
        units = np.asarray(elements.units, dtype=np.float64)
        kind = np.asarray(elements.kind)
        scale = np.asarray(elements.scale, dtype=np.float64)
        near = np.zeros(n0, dtype=bool)
        near[self.free[rows] // 3] = True
        el = np.flatnonzero(near[conn].any(axis=1) & (kind >= 0))
        indptr, indices, indptr_b, blockmap = grid_block_pattern(conn[el], n0)
        data = np.zeros(len(indices))
        for k in np.unique(kind[el]):
            mine = kind[el] == k
            scatter_blocks(units[k][None], conn[el][mine], blockmap[mine], indptr_b, data, scale=scale[el][mine])
        del blockmap
        n = 3 * n0
        block = free_block(sp.csr_matrix((data, indices, indptr), shape=(n, n)), self.free, overwrite=True)
        return sp.csr_matrix(block[rows])

    def _first_plan(self):
        """What :meth:`first_level` needs besides the element matrices (geometry only; built once)."""
        if self._plan is None:
            from ...._linalg import free_block
            from ...models.voxel._kernels import grid_block_pattern

            ijk0, conn0, n0, shape0 = self.geometry[0]
            ijk1, conn1, n1, shape1 = self.geometry[1]
            f = np.array(_factors(shape0))
            cvox = ijk0 // f
            parent = np.searchsorted(_voxel_keys(ijk1, shape1), _voxel_keys(cvox, shape1))
            pos = ijk0 - cvox * f
            child = (pos[:, 0] * 2 + pos[:, 1]) * 2 + pos[:, 2]
            free_mask = np.zeros(3 * n0, dtype=bool)
            free_mask[self.free] = True
            el_free = free_mask[(3 * conn0)[:, :, None] + np.arange(3)].reshape(len(conn0), 24)
            indptr, indices, indptr_b, blockmap = grid_block_pattern(conn1, n1)
            n_data = len(indices)
            # the kept block's pattern and its entries' positions in the full coarse matrix's data (the
            # gather run on the positions themselves; the full pattern's indices are not kept)
            block = free_block(sp.csr_matrix((np.arange(n_data, dtype=indices.dtype), indices, indptr),
                                             shape=(3 * n1, 3 * n1)), self.coarse_free[0], overwrite=True)
            del indices, indptr
            self._plan = (parent, child, _child_transfers(f), el_free, conn1, blockmap, indptr_b, n_data,
                          block.data.copy(), block.indptr, block.indices.copy())
        return self._plan

    def solver(self, A, *, smoother: str = "gauss-seidel", sweeps: int = 1, stale: bool = False, elements=None,
               precision: str = "auto"):
        """A pyamg ``MultilevelSolver`` on this hierarchy for the free-DOF matrix A (F, F).

        The last one is remembered without its finest matrix (no copy of A is
        kept): the same matrix (:func:`_fingerprint`: sampled pattern and values),
        e.g. a constant stiffness over load steps, reuses its coarse levels.
        A fingerprint collision would only cost iterations: CG checks the true
        residual.  Call :meth:`release` after solving to drop the reference to A.

        With ``stale=True`` a matrix of the same pattern but other values (the
        next Newton iteration's tangent) also gets the remembered coarse levels,
        with A as the finest level (smoothing and residuals use A itself), when
        :meth:`may_reuse` allows it; the returned solver's ``stale`` attribute
        says whether its coarse levels are those of an earlier matrix.
        ``elements``: A as voxel element matrices (:class:`ElementMatrices`),
        from which the first coarse level is formed (:meth:`first_level`).
        ``precision``: see :func:`multigrid_preconditioner`.
        """
        import pyamg
        from pyamg.relaxation.smoothing import change_smoothers

        free_op = _matrix_free(A)
        if free_op:
            # a matrix-free block (FreeStiffness): the finest level is its stencil, the first coarse level its
            # element matrices' sum; no stale reuse (its values never change), no stored finest matrix
            if elements is None:
                elements = A.elements
            if smoother != "gauss-seidel" or not self.prolongations:
                raise InputError("a matrix-free block needs the Gauss-Seidel smoother and at least two levels")
            stale = False
        else:
            A = sp.csr_matrix(A)
        single = len(self.prolongations) > 0 and (precision == "single" or
                                                   (precision == "auto" and (free_op or A.nnz <= SINGLE_MAX_ENTRIES)))
        key = (_operator_key(A) if free_op else _fingerprint(A), smoother, sweeps, single)
        if self._last is not None and (self._last[0] == key or (stale and self.may_reuse(key))):
            ml = self._last[1]
            if ml.fine is None or self._last[0] != key:  # a stencil is kept only for its own matrix
                ml.fine = None
                ml.levels[0].A = _single(A) if ml.single else A
                ml.levels[0].presmoother, ml.levels[0].postsmoother = ml.csr_smoothers
            ml.stale = self._last[0] != key
            if ml.stale:
                self.stale_solves += 1
            return ml
        mats = self.galerkin(A, elements)
        fine = self.stencil(A, elements) if elements is not None and smoother == "gauss-seidel" and \
            self.prolongations else None
        if free_op and fine is None:
            raise InputError("a matrix-free block needs a voxel stencil: no node has all its neighbours free")
        levels = []
        for lvl, M in enumerate(mats):
            L = pyamg.multilevel.MultilevelSolver.Level()
            L.A = fine if (lvl == 0 and fine is not None) else (_single(M) if single else M)
            if lvl < len(self.prolongations):
                L.P, L.R = (self._single_transfers()[lvl] if single else (self.prolongations[lvl],
                                                                           self.restrictions[lvl]))
            levels.append(L)
        coarse = _CoarseSolver(mats[-1], single=single)
        ml = pyamg.multilevel.MultilevelSolver(levels, coarse_solver=coarse)
        ml.single = single
        if smoother == "gauss-seidel":  # forward before, backward after: a symmetric cycle
            pre = ("gauss_seidel", {"sweep": "forward", "iterations": sweeps})
            post = ("gauss_seidel", {"sweep": "backward", "iterations": sweeps})
        elif smoother == "symmetric-gauss-seidel":
            pre = post = ("gauss_seidel", {"sweep": "symmetric", "iterations": sweeps})
        else:
            pre = post = ("jacobi", {"omega": 2.0 / 3.0, "iterations": sweeps})
        change_smoothers(ml, pre, post)
        ml.csr_smoothers = (getattr(ml.levels[0], "presmoother", None), getattr(ml.levels[0], "postsmoother", None))
        ml.fine = fine
        if fine is not None:  # the finest level applied from the stencil: the same sweeps and residuals

            def pre_sweeps(_, x, b):
                for _ in range(sweeps):
                    fine.sweep(x, b, forward=True)

            def post_sweeps(_, x, b):
                for _ in range(sweeps):
                    fine.sweep(x, b, forward=False)

            ml.levels[0].presmoother, ml.levels[0].postsmoother = pre_sweeps, post_sweeps
        ml.stale = False
        self._last = (key, ml)
        self.stale_solves, self.fresh_iterations, self.refresh = 0, None, False
        return ml

    def _single_transfers(self):
        """The prolongations and restrictions in single precision (made once)."""
        if self._single_pr is None:
            self._single_pr = [(_single(P), _single(R)) for P, R in zip(self.prolongations, self.restrictions)]
        return self._single_pr

    def may_reuse(self, key) -> bool:
        """Whether a matrix with fingerprint ``key`` may be solved on the remembered (stale) coarse levels.

        Yes when the pattern, smoother and sweeps are those of the remembered
        solver, a solve on its fresh levels has been reported
        (:meth:`report`), fewer than :data:`MAX_STALE_SOLVES` solves have used
        it since, and none of them took more than :data:`STALE_GROWTH` times
        the fresh solve's iterations.
        """
        if self._last is None or self.refresh or self.fresh_iterations is None:
            return False
        last = self._last[0]
        same_pattern = last[0][0] == key[0][0] and last[1:] == key[1:]
        return same_pattern and self.stale_solves < MAX_STALE_SOLVES

    def report(self, iterations: int, ok: bool, stale: bool) -> None:
        """Record a CG solve's iterations on the remembered levels (fresh or stale), for :meth:`may_reuse`."""
        if not stale:
            self.fresh_iterations = int(iterations) if ok else None
        elif not ok or iterations > STALE_GROWTH * max(self.fresh_iterations or 0, 1) + 2:
            self.refresh = True

    def release(self) -> None:
        """Drop the remembered solver's reference to the finest matrix (the coarse levels stay; a
        :class:`VoxelStencil` holds copies of its stored rows, not the matrix, and stays too)."""
        if self._last is not None and self._last[1].fine is None:
            self._last[1].levels[0].A = None


def _matrix_free(A) -> bool:
    """Whether A is a matrix-free block (:class:`~voxflex.deform.models.voxel.elements.FreeStiffness`)."""
    from ...models.voxel.elements import FreeStiffness

    return isinstance(A, FreeStiffness)


def _single(M):
    """A CSR matrix in single precision, sharing M's index arrays."""
    return sp.csr_matrix((M.data.astype(np.float32), M.indices, M.indptr), shape=M.shape)


FINGERPRINT_SAMPLES = 4096


"""Entries of each of A's arrays that :func:`_fingerprint` reads (evenly spaced)."""


def _fingerprint(A):
    """A cheap key of the CSR matrix A: ``((shape, entries, dtype, pattern samples), value samples)``, with
    CRC-32s of :data:`FINGERPRINT_SAMPLES` evenly spaced entries of each of its three arrays.

    It reads ~100 kB whatever the size: CRC-32s of the whole arrays took 6 % of a linear solve at
    6.4 million DOF and 50 ms of each Newton iteration at 55k DOF.  Equal matrices (a constant
    stiffness over load steps, or its copy) have equal keys; a new tangent differs in its sampled
    values.  A false match (another matrix equal at every sample, e.g. a change confined to a few
    voxels) reuses coarse levels of the other values, which costs CG iterations, not accuracy: the
    finest level is always A itself, or a stencil of element matrices that the answer is checked
    against (see :func:`voxflex.deform.solve.linear.solve_linear`).
    """
    import zlib

    def sample(a):
        step = max(1, len(a) // FINGERPRINT_SAMPLES)
        return zlib.crc32(np.ascontiguousarray(a[::step]))

    return (A.shape, A.nnz, A.data.dtype.str, sample(A.indptr), sample(A.indices)), sample(A.data)


def _operator_key(A):
    """The key of a matrix-free block, like :func:`_fingerprint`: its shape, its element matrices (CRC-32 of
    the distinct ones, a few kB) and samples of the voxels' kinds and scales (the hierarchy it is cached in
    fixes the grid and the free DOFs)."""
    import zlib

    e = A.elements

    def sample(a):
        a = np.asarray(a)
        step = max(1, len(a) // FINGERPRINT_SAMPLES)
        return zlib.crc32(np.ascontiguousarray(a[::step]))

    units = zlib.crc32(np.ascontiguousarray(e.units, dtype=np.float64))
    return ("matrix-free",) + tuple(A.shape), (units, sample(e.kind), sample(e.scale))


def hierarchy(grid, free=None, *, max_coarse: int = MAX_COARSE, max_coarse_cubic: int = MAX_COARSE_CUBIC,
              max_levels: int = MAX_LEVELS) -> VoxelHierarchy:
    """The multigrid hierarchy of a voxel grid's free DOFs, cached.

    Parameters
    ----------
    grid : TrilinearGrid
        The voxel model's grid (``model.grid``).
    free : (F,) int, optional
        Sorted unique free DOFs (``3 * node + component``); default all.
    max_coarse : int
        Coarsen until a level has at most this many free DOFs...
    max_coarse_cubic : int
        ...or this many, or 1/:data:`CUBIC_FRACTION` of the finest level's free
        DOFs if that is more, while every axis of the level is longer than one
        voxel (the next level's voxels are then cubes again).  Coarsening a level
        with a one-voxel axis (a plate) flattens the coarse voxels, and a coarse
        space of flat voxels is poor for near-incompressible bending: the
        24x24x1 plate at nu = 0.49 took 100 CG iterations with a 1014-DOF
        coarsest level (12x12x1), 209 with the next (6x6x1).  Where the voxels
        stay cubes a smaller coarsest level costs an iteration or none (clamped
        beam under gravity, rtol 1e-8, 1275 against 243 DOFs: 12 and 12 at
        32x8x8; 12 and 13 at 64x16x16 and 128x32x32) and saves the larger
        factorisation at every Newton iteration: the 1275-DOF sparse LU took
        11 ms of each ~90 ms iteration of the 32x8x8 neo-Hooke beam, the
        243-DOF one 1 ms (its 31-iteration run, alternated 4 times: 2.80-3.38
        against 3.58-3.94 CPU s).  On a large grid that extra iteration costs
        more than the factorisation (64x16x16, one solve, alternated 5 times:
        0.64-0.82 against 0.60-0.71 s), hence the fraction: from about 40k
        free DOFs the coarsest level stays as :data:`MAX_COARSE` leaves it.
    max_levels : int
        At most this many levels (the finest included).

    Returns
    -------
    VoxelHierarchy
        The same object for the same grid and free DOFs (the last 4 are kept).

    Raises
    ------
    InputError
        ``grid`` is not a TrilinearGrid, ``free`` not sorted unique DOF indices.
    """
    if not isinstance(grid, TrilinearGrid):
        raise InputError(f"grid must be a TrilinearGrid (the voxel model's model.grid), got {type(grid).__name__}")
    n = 3 * grid.n_nodes
    free = np.arange(n) if free is None else np.asarray(free)
    if free.ndim != 1 or free.dtype.kind not in "iu" or (len(free) and (free[0] < 0 or free[-1] >= n)) or \
            np.any(np.diff(free) <= 0):
        raise InputError(f"free must be sorted unique DOF indices in [0, {n}) (3 * node + component)")
    if int(max_coarse) < 1 or int(max_coarse_cubic) < 1 or int(max_levels) < 1:
        raise InputError("max_coarse, max_coarse_cubic and max_levels must be at least 1")
    key = (id(grid), len(free), int(max_coarse), int(max_coarse_cubic), int(max_levels))
    for k, (g, fr, h) in _cache.items():
        if k == key and g is grid and np.array_equal(fr, free):
            _cache.move_to_end(k)
            return h
    h = _build_impl(grid, free.astype(np.int64), int(max_coarse), int(max_coarse_cubic), int(max_levels))
    _cache[key] = (grid, free.copy(), h)
    while len(_cache) > _CACHE_SIZE:
        _cache.popitem(last=False)
    return h


_cache: "OrderedDict[tuple, tuple]" = OrderedDict()


def clear_cache() -> None:
    """Forget the cached hierarchies (they hold references to their grids)."""
    _cache.clear()


def _build_impl(grid, free, max_coarse, max_coarse_cubic, max_levels):
    ijk, conn, n_nodes, shape = grid.element_ijk, grid.element_nodes, grid.n_nodes, tuple(grid.shape)
    Ps, Rs, shapes, kept = [], [], [shape], []
    geometry = [(ijk, conn, n_nodes, shape)]
    level_free = free
    cubic = min(max_coarse, max(max_coarse_cubic, len(free) // CUBIC_FRACTION))
    while len(shapes) < max_levels and max(shape) > 1 and \
            len(level_free) > (cubic if min(shape) > 1 else max_coarse):
        Pn, ijk, conn, shape = node_prolongation(ijk, conn, n_nodes, shape)
        n_nodes = Pn.shape[1]
        P, level_free = dof_prolongation(Pn, level_free, n_nodes)
        if P.shape[1] >= P.shape[0]:  # no reduction (cannot happen with 2x coarsening, kept as a guard)
            break
        Ps.append(P)
        Rs.append(sp.csr_matrix(P.T))
        shapes.append(shape)
        kept.append(level_free)
        if len(geometry) < 2:
            geometry.append((ijk, conn, n_nodes, shape))
    return VoxelHierarchy(Ps, Rs, shapes, free.copy(), kept, geometry, grid)


def multigrid_preconditioner(A, grid, free=None, *, smoother: str = "gauss-seidel", sweeps: int = 1,
                             max_coarse: int = MAX_COARSE, max_coarse_cubic: int = MAX_COARSE_CUBIC,
                             stale: bool = False, elements=None, precision: str = "auto"):
    """V-cycle preconditioner ``r -> z ~ A^{-1} r`` for the free-DOF matrix of a voxel model.

    Parameters
    ----------
    A : (F, F) sparse symmetric positive definite
        ``H[free][:, free]`` of a voxel model's Hessian.
    grid : TrilinearGrid
    free : (F,) int, optional
        Sorted free DOFs (default all ``3 * grid.n_nodes``).
    smoother : {"gauss-seidel", "symmetric-gauss-seidel", "jacobi"}
        Gauss-Seidel forward before the coarse correction and backward after
        it (the cycle stays symmetric); a symmetric sweep (forward then
        backward) on both sides; or damped Jacobi (omega = 2/3) on both sides.
        Measured on the 55k-DOF beam (rtol 1e-8, coarsest level 36 DOFs):
        18 iterations / 0.37 s, 15 / 0.58 s and 26 / 0.77 s (2 sweeps).
    sweeps : int
        Smoother iterations on each side.
    max_coarse, max_coarse_cubic : int
        Where coarsening stops (see :func:`hierarchy`).
    stale : bool
        Allow the coarse levels of an earlier matrix of the same pattern
        (see :meth:`VoxelHierarchy.solver`); ``ml.stale`` says whether they were used.
    elements : ElementMatrices, optional
        A as voxel element matrices: the first coarse level is formed from them
        (:meth:`VoxelHierarchy.first_level`) instead of by a sparse product.
    precision : {"auto", "single", "double"}
        Arithmetic of the cycle.  ``"single"`` runs it on float32 copies of the
        level matrices (the finest one shares A's index arrays; the coarsest is
        still factorised in double), with the residual scaled to unit size
        before it is rounded: the cycle then moves 8 instead of 12 bytes per
        stored entry.  CG itself stays in double precision on A, so the answer
        meets its tolerance as before; the cycle is symmetric only to
        single-precision round-off (about 1e-6 instead of 1e-15), which PCG
        tolerates.  Measured (rtol 1e-8, iterations double / single): the
        64x16x16 beam 12 / 12 (a cycle 13.5-21 ms / 9.4-9.9 ms), at nu = 0.49 48 /
        48, 128x32x32 12 / 12, the 24x24x1 plate at nu = 0.49 121 / 133, 64x64x1
        148 / 158, two materials 1e6 and 1e9 apart 24 / 24.  ``"auto"``: single
        up to :data:`SINGLE_MAX_ENTRIES` stored entries of A, double beyond.

    Returns
    -------
    apply : callable (F,) -> (F,)
        One V-cycle from a zero guess: symmetric positive definite.
    ml : pyamg MultilevelSolver
        It holds A until ``hierarchy(grid, free).release()``.
    """
    check_choice("multigrid smoother", smoother, SMOOTHERS)
    check_choice("multigrid precision", precision, PRECISIONS)
    if int(sweeps) < 1:
        raise InputError(f"sweeps must be at least 1, got {sweeps}")
    h = hierarchy(grid, free, max_coarse=max_coarse, max_coarse_cubic=max_coarse_cubic)
    if A.shape != (len(h.free), len(h.free)):
        raise InputError(f"matrix shape {A.shape} does not match the {len(h.free)} free DOFs of the grid")
    ml = h.solver(A, smoother=smoother, sweeps=int(sweeps), stale=stale, elements=elements, precision=precision)
    return _vcycle(ml), ml


def _vcycle(ml):
    """One V-cycle of pyamg's multilevel solver from x = 0, without its residual-norm bookkeeping."""
    cycle = getattr(ml, "_MultilevelSolver__solve", None)
    if cycle is None or len(ml.levels) == 1:  # pyamg changed its internals, or a single level
        return lambda r: ml.solve(r, maxiter=1, cycle="V", tol=1e-300)

    if getattr(ml, "single", False):
        def apply(r):
            # single precision: scaled to unit size first (a tiny residual must not underflow)
            s = float(np.abs(r).max())
            if not s > 0.0:
                return np.zeros_like(r)
            r32 = (r * (1.0 / s)).astype(np.float32)
            x = np.zeros_like(r32)
            cycle(0, x, r32, "V", 1)
            return x.astype(np.float64) * s

        return apply

    def apply(r):
        x = np.zeros_like(r)
        cycle(0, x, r, "V", 1)
        return x

    return apply
