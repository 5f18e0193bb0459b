"""The configurations of a trade-off sweep and how each one runs.

A :class:`Configuration` is one model of the sweep (the voxel reference, a coarser voxel grid or a reduced
configuration), set up as a scene.  Each one is built and simulated with BLAS, OpenMP and numba pinned to
one thread, after an untimed warm-up run of the smallest configuration of its kind (once per process), as
the median of 3 runs when a run takes less than a second; the runs go one after the other here, or on Dask
workers.  What a run returns are raw measurements; :mod:`voxflex.sweep` turns them into the rows of the
table.
"""

from __future__ import annotations

import contextlib
import dataclasses
import statistics
import time
import warnings
from dataclasses import dataclass

import numpy as np

from .deform.models.kinds import node_kind
from .errors import ConvergenceError, InputError
from .sampling.quadrature import REGION_RULES
from .scene import OutputSpec, Scene

_SHORT_RUN = 1.0  # seconds: shorter runs are timed 3 times and the median reported


# ---------------------------------------------------------------------------
# configurations
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Configuration:
    """One model of the sweep.

    ``kind`` names a :class:`~voxflex.deform.models.kinds.NodeKind`: the reference kind (the voxel
    model on the image of grid ``level``: 0 the scene's image, 1 every voxel split in 2x2x2, -1 / -2
    ... 2x / 4x coarser) or a reduced kind (frames on the scene's image).
    """

    kind: str
    role: str = "reduced"  # "reference", "refinement" (coarser voxel grids) or "reduced"
    level: int = 0
    count: int | None = None
    shape_function: str | None = None
    quadrature: str = "gauss-legendre"
    samples: int | None = None

    def label(self) -> str:
        kind = node_kind(self.kind)
        if kind.reference:
            return f"{kind.name} level {self.level:+d}"
        extra = f" {self.samples} samples" if self.samples is not None else ""
        return f"{self.count} frames {self.shape_function} {self.quadrature}{extra}"

    def scene(self, scene: Scene) -> Scene:
        """``scene`` set up for this configuration (no output file: a sweep writes no result)."""
        nodes, elasticity = scene.nodes, scene.elasticity
        if node_kind(self.kind).reference:
            nodes = dataclasses.replace(nodes, kind=self.kind, shape_function=None, count=None, positions=None)
            elasticity = dataclasses.replace(elasticity, quadrature=self.quadrature, samples=None)
        else:
            nodes = dataclasses.replace(nodes, kind=self.kind, count=self.count, shape_function=self.shape_function)
            samples = self.samples if self.samples is not None else elasticity.samples
            elasticity = dataclasses.replace(elasticity, quadrature=self.quadrature,  # no region count for points
                                             samples=samples if self.quadrature in REGION_RULES else None)
        return dataclasses.replace(scene, nodes=nodes, elasticity=elasticity, output=OutputSpec())


def _warm_key(c: Configuration):
    return (c.kind, c.quadrature, c.shape_function)


# -- running --------------------------------------------------------------------
def _run_all(tasks, workers, scheduler, bar) -> list:
    if workers is None and scheduler is None:
        out = []
        for task in tasks:
            out.append(_task(*task))
            if bar is not None:
                bar.update(1)
        return out
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise InputError('distributed sweeps need Dask: pip install "voxflex[dask]" (or dask[distributed]); '
                         "or run without workers/scheduler") from None
    with contextlib.ExitStack() as stack:
        if scheduler is not None:
            try:
                client = stack.enter_context(Client(scheduler, timeout=10))
            except (OSError, TimeoutError, ValueError) as exc:
                raise InputError(f"cannot reach the Dask scheduler at '{scheduler}' ({exc}); check the address "
                                 "and that the scheduler runs") from None
        else:
            # dashboard on a free port (None means the default 8787 here, and a warning when it is taken)
            cluster = stack.enter_context(LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True,
                                                       dashboard_address=":0"))
            client = stack.enter_context(Client(cluster))
        futures = [client.submit(_task, *task, pure=False) for task in tasks]
        for _ in as_completed(futures):
            if bar is not None:
                bar.update(1)
        return client.gather(futures)


_WARMED: set = set()  # warm-up keys already run in this process (one per worker process under Dask)


@contextlib.contextmanager
def _pinned():
    """BLAS and OpenMP at one thread, numba at one thread: timings of one core, results independent of threads."""
    import numba
    from threadpoolctl import threadpool_limits

    before = numba.get_num_threads()
    with threadpool_limits(limits=1):
        numba.set_num_threads(1)
        try:
            yield
        finally:
            numba.set_num_threads(before)


def _task(scene, image, config, warm, warm_image) -> dict:
    """Run one configuration (after its warm-up, once per process): raw measurements, or ``{"error": why}``."""
    key = (_warm_key(warm), warm.level, warm.count, warm.samples)
    if key not in _WARMED:
        _WARMED.add(key)
        try:
            _measure(scene, warm_image, warm, repeat=False)  # untimed
        except Exception:  # noqa: BLE001 - a failure shows in the configuration's own run
            pass
    return _measure(scene, image, config, repeat=True)


def _measure(scene, image, config, *, repeat: bool) -> dict:
    from .build import model as build_model
    from .simulation import simulate

    s = config.scene(scene)
    with warnings.catch_warnings(record=True) as caught, _pinned():
        warnings.simplefilter("always")
        try:
            pre, solve = [], []
            first = None
            while True:
                t0 = time.perf_counter()
                # never from the on-disk precompute cache: the column is what building the model costs (the
                # repeats, and a sweep run before, would otherwise time a cache load: 5 ms for 0.3 s)
                m = build_model(s, image=image, cache=False)
                t1 = time.perf_counter()
                result = simulate(s, model=m, progress=False)
                t2 = time.perf_counter()
                pre.append(t1 - t0)
                solve.append(t2 - t1)
                if first is None:
                    first = (m, result)
                if not repeat or len(pre) >= 3 or (len(pre) == 1 and pre[0] + solve[0] >= _SHORT_RUN):
                    break
        except (InputError, ConvergenceError, NotImplementedError) as exc:
            return {"error": str(exc).splitlines()[0]}
        except Exception as exc:  # noqa: BLE001 - one broken configuration must not lose the sweep
            if config.role == "reference":
                raise
            return {"error": f"failed with {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''} "
                             "(an error in voxflex, please report it)"}
    m, result = first
    notes = list(dict.fromkeys(str(w.message).splitlines()[0] for w in caught))
    describe = m.describe()
    steps = max(len(result.time) - 1, 1)
    dynamic = scene.solver.kind == "implicit-euler"
    solve_s = statistics.median(solve)
    return {
        "dofs": int(describe.get("dofs", np.asarray(m.rest).size)),
        "samples": int(describe.get("samples", 0)),
        "voxel_size": float(np.max(image.spacing)),
        "precompute_seconds": statistics.median(pre),
        "solve_seconds": solve_s / steps if dynamic else solve_s,
        "total_seconds": statistics.median(pre) + solve_s,
        "steps": steps,
        "newton_iterations": int(np.sum(result.newton_iterations)),
        "probes": {k: np.asarray(v) for k, v in result.probes.items()},
        "surface_rest": np.asarray(result.surface_rest),
        "surface_positions": np.asarray(result.surface_positions),
        "energy": np.asarray(result.energy_elastic) + np.asarray(result.energy_kinetic),
        "notes": notes,
    }
