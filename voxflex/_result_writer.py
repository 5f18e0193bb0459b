"""Streaming a result file state by state (:class:`ResultWriter`; the layout: :mod:`voxflex._result_layout`).

:meth:`voxflex.result.Result.save` writes through it too, so there is one writer of the format.
"""

from __future__ import annotations

import numpy as np

from ._result_layout import _BLOCK_BYTES, _CHUNK_BYTES, _FORMAT, _INT_SERIES, STATIC, TOTALS

__all__ = ["ResultWriter"]


class ResultWriter:
    """Write a result file state by state, with memory bounded whatever the number of states.

    The static part (image, rest surface and nodes, scene, model) is written at
    once; every per-state dataset (:data:`SERIES`, :data:`SERIES_GROUPS`) is a
    resizable, chunked, gzip-compressed dataset to which :meth:`append` adds
    one state (up to 64 states or about 4 MiB are buffered, then written).  The
    layout is the one :meth:`Result.save` writes (it uses this class) and
    :meth:`Result.load` reads.  The writer does not rename anything: give it
    the temporary path of :func:`voxflex._atomic.atomic_path`.

    Parameters
    ----------
    path : path
        The file to create (replaced when it exists).
    static : Result or mapping
        Holds the :data:`STATIC` values (attributes of a Result or keys of a mapping).

    Examples
    --------
    >>> writer = ResultWriter(tmp, result)                     # doctest: +SKIP
    >>> writer.append({"time": 0.0, "nodes/state": q0, ...})   # doctest: +SKIP
    >>> writer.close(complete=True, totals={"steps": 1})       # doctest: +SKIP
    """

    def __init__(self, path, static):
        import h5py

        get = static.get if isinstance(static, dict) else static.__getattribute__
        head = {k: get(k) for k in STATIC}
        self.states = 0
        self._datasets = {}
        self._buffer = []
        self._block = None
        self._keys = None
        self._location = str(head["cell_location"])
        self._f = h5py.File(path, "w")
        f = self._f
        comp = dict(compression="gzip", compression_opts=4, shuffle=True)

        def put(group, name, data):
            data = np.asarray(data)
            if data.size == 0:
                return group.create_dataset(name, data=data)
            return group.create_dataset(name, data=data, chunks=True, **comp)

        f.attrs["voxflex_version"] = str(head["version"])
        f.attrs["scene"] = str(head["scene"])
        f.attrs["format"] = _FORMAT
        f.attrs["node_kind"] = str(head["node_kind"])
        f.attrs["complete"] = False  # until close() says otherwise
        g = f.create_group("model")
        for key, value in dict(head["model"]).items():
            g.attrs[key] = value
        for name in ("probes", "energy", "stats"):
            f.create_group(name)
        g = f.create_group("surface")
        put(g, "rest", np.asarray(head["surface_rest"], dtype=float))
        put(g, "faces", np.asarray(head["surface_faces"], dtype=np.int64))
        put(f.create_group("nodes"), "rest", np.asarray(head["nodes_rest"], dtype=float))
        if head["cable_point_cable"] is not None:  # the cable of each row of /cable/points
            put(f.require_group("cable"), "point_cable", np.asarray(head["cable_point_cable"], dtype=np.int64))
        _write_problem(f.create_group("problem"), head["problem"] or {})
        g = f.create_group("image")
        d = put(g, "labels", np.asarray(head["image_labels"]))
        for key in ("spacing", "origin", "direction"):
            value = np.asarray(head[f"image_{key}"], dtype=float)
            d.attrs[key] = value
            g.attrs[key] = value

    # -- states -----------------------------------------------------------
    def append(self, row) -> None:
        """Add one state: ``row`` maps file paths (``"time"``, ``"nodes/state"``, ``"probes/tip"`` ...) to its values.

        Every state must carry the same paths as the first one.
        """
        if self._keys is None:
            self._keys = tuple(row)
            nbytes = sum(np.asarray(v).nbytes for v in row.values()) or 1
            self._block = int(max(1, min(64, _BLOCK_BYTES // nbytes)))
        elif tuple(row) != self._keys:
            raise ValueError(f"state {self.states + len(self._buffer)} has datasets {sorted(row)}, "
                             f"the first had {sorted(self._keys)}")
        self._buffer.append(row)
        if len(self._buffer) >= self._block:
            self.flush()

    def append_block(self, rows) -> None:
        """Add several states at once: ``rows`` maps file paths to arrays (T, ...) with the same T."""
        self.flush()
        if self._keys is None:
            self._keys = tuple(rows)
            self._block = 1
        elif tuple(rows) != self._keys:
            raise ValueError(f"block has datasets {sorted(rows)}, the first state had {sorted(self._keys)}")
        lengths = {np.shape(v)[0] for v in rows.values()}
        if len(lengths) != 1:
            raise ValueError(f"a block's datasets differ in their number of states: {sorted(lengths)}")
        self._write({k: np.asarray(v) for k, v in rows.items()}, lengths.pop())

    def flush(self) -> None:
        """Write the buffered states."""
        if not self._buffer:
            return
        rows = self._buffer
        self._buffer = []
        self._write({k: np.stack([np.asarray(r[k]) for r in rows]) for k in self._keys}, len(rows))

    def _write(self, block, count) -> None:
        for path, values in block.items():
            d = self._datasets.get(path)
            if d is None:
                d = self._create(path, values)
            values = values.astype(d.dtype, copy=False)
            d.resize(self.states + count, axis=0)
            d[self.states:] = values
        self.states += count

    def _create(self, path, values):
        dtype = np.int64 if path in _INT_SERIES else float
        tail = values.shape[1:]
        row = int(np.prod(tail, dtype=np.int64)) * 8
        kw = {}
        if row:
            # chunks of about _CHUNK_BYTES: several states of a small row, or one state split along axis 1
            t = int(max(1, min(4096, _CHUNK_BYTES // row)))
            chunks = (t, *tail)
            if row > _CHUNK_BYTES and tail:
                per = row // tail[0]
                chunks = (1, int(max(1, min(tail[0], _CHUNK_BYTES // max(per, 1)))), *tail[1:])
            kw = dict(chunks=chunks, compression="gzip", compression_opts=4, shuffle=True)
        else:
            kw = dict(chunks=tuple(max(1, n) for n in (64, *tail)))
        group, _, name = path.rpartition("/")
        parent = self._f.require_group(group) if group else self._f
        d = parent.create_dataset(name, shape=(0, *tail), maxshape=(None, *tail) if row else (None,) * (1 + len(tail)),
                                  dtype=dtype, **kw)
        if path.startswith("fields/"):
            d.attrs["location"] = self._location
        self._datasets[path] = d
        return d

    # -- end --------------------------------------------------------------
    def close(self, *, complete: bool = True, error: str = "", totals=None) -> None:
        """Write the buffered states, the ``complete`` / ``error`` attributes and the run's ``totals``, and close."""
        self.flush()
        f = self._f
        lengths = {p: d.shape[0] for p, d in self._datasets.items()}
        if not self.states or any(n != self.states for n in lengths.values()):
            raise ValueError(f"a result file needs the same number (>= 1) of states in every dataset, got {lengths}")
        f.attrs["complete"] = bool(complete)
        if error:
            f.attrs["error"] = str(error)
        for key, value in dict(totals or {}).items():
            if value is not None:
                f["stats"].attrs[key] = TOTALS[key](value)
        f.close()

    def abort(self) -> None:
        """Close the file as it is (after a failure; the caller discards it).  Safe to call after :meth:`close`."""
        if self._f.id.valid:
            self._f.close()


def _write_problem(g, problem: dict) -> None:
    """``/problem``: the title, solver kind, end time and gravity as attributes; one group per obstacle and per
    fixed region (``obstacles/0``, ``fixed/0`` ...) with its values as attributes."""
    for key in ("title", "solver_kind", "end_time"):
        if key in problem:
            g.attrs[key] = problem[key]
    if problem.get("gravity") is not None:
        g.attrs["gravity"] = np.asarray(problem["gravity"], dtype=float)
    for name in ("obstacles", "fixed"):
        h = g.create_group(name)
        for i, item in enumerate(problem.get(name, ())):
            s = h.create_group(str(i))
            for key, value in item.items():
                s.attrs[key] = np.asarray(value, dtype=float) if isinstance(value, (tuple, list, np.ndarray)) else value
