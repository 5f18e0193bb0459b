"""Run a scene: image -> model -> boundary conditions -> solver -> :class:`Result`.

The model comes from :func:`voxflex.build.model` (the registry keyed by
``[nodes] kind``), or is given; everything here talks to it through the model
protocol (:mod:`voxflex.deform.models.protocol`).  Layers are built only when needed:
the mass matrix only for dynamics (the solver builds it), densities only for
gravity or dynamics, probe mappings only for probes, the boundary surface
once (the result file always carries it).

Beyond positions the result carries, per state, the inversion statistics
(samples with det F <= 0 and the smallest det F) and the fields ``[output]
fields`` asks for (:mod:`voxflex.deform.models.fields`; reactions of the fixed
regions).  A run whose later step fails still returns its converged steps:
the result file is written marked incomplete and the error is raised after.

The solver hands every step's record to a recorder (its ``sink``) instead of
keeping it: the recorder computes the state's row, appends it to the result
file (streamed into the atomic temporary, :class:`voxflex.result.ResultWriter`)
and holds only what ``keep`` asks, so memory does not grow with the steps.

Example
-------
>>> import voxflex as vf
>>> result = vf.simulate("examples/cantilever.toml", progress=False)   # doctest: +SKIP
>>> result.probes["tip"][-1]                                             # doctest: +SKIP
"""

from __future__ import annotations

import os
import time
import warnings

import numpy as np

from ._version import __version__
from .deform.models.protocol import begin_run
from .errors import ConvergenceError, InputError
from .result import AUTO_KEEP_BYTES, Result
from .problems import problem_of  # noqa: F401 - the one translation (re-exported; it lives below build.py)
from .scene import as_scene

__all__ = ["simulate", "problem_of", "InversionWarning", "RoundoffWarning", "CANNOT_RECOVER", "AUTO_KEEP_BYTES"]


class RoundoffWarning(UserWarning):
    """Steps were accepted at the round-off floor of double precision, above ``[solver] tolerance``: the
    forces of the stiffest parts are known only to about eps |K x|, so the residual cannot go lower
    (large stiffness contrasts).  The states are the best double precision gives; the warning says how
    far above the tolerance they stopped."""


ROUNDOFF_WARN = 100.0
"""A run whose steps stopped at the round-off floor more than this many times above the tolerance warns
(:class:`RoundoffWarning`); a floor a little above a tolerance asked near round-off (1e-10) does not."""


class InversionWarning(UserWarning):
    """Samples of a material that cannot recover from inversion (StVK, polar corotational Hooke) inverted."""


CANNOT_RECOVER = "stvk, and hooke (or hooke-orthotropic) with the polar corotational strain"
"""The materials :class:`InversionWarning` is about (their energy stays finite, and may even fall, when inverted)."""


def _cannot_recover(material) -> bool:
    """StVK (any strain) and Hooke laws over the polar corotational strain: an inverted sample
    has a finite, even decreasing, energy and is not pushed back."""
    name = getattr(material, "name", "")
    strain = getattr(getattr(material, "strain", None), "name", "")
    return name == "stvk" or (name in ("hooke", "hooke-orthotropic") and strain == "corotational")


def simulate(scene, *, progress: bool = True, output=None, model=None, verbose: bool = False,
             cache: bool = True, keep=None, every=None, force: bool = False) -> Result:
    """Run a scene and return its :class:`~voxflex.result.Result`.

    Parameters
    ----------
    scene : Scene or path to a scene TOML file
    progress : bool
        Show a progress bar on stderr for the solver steps (see ``voxflex._progress``).
    output : path, optional
        Where to write the result file; defaults to the scene's ``[output] file``
        when it has one, otherwise nothing is written.  The states are streamed to
        a temporary file beside it step by step (memory does not grow with the
        steps), which replaces ``output`` only when the run ends: an interrupted or
        failed run leaves an existing file as it was.
    keep : "auto", "all", "last" or int N >= 1, optional
        Default: the scene's ``[output] keep`` ("auto" unless set).  Which recorded states the returned Result holds in memory (the file always
        has all of them): ``"all"``; ``"last"``, the rest state and the last state;
        N, the rest state and the last N states.  ``"auto"`` (default) is ``"all"``
        without a result file, and with one ``"all"`` while they need at most
        :data:`AUTO_KEEP_BYTES`, else ``"last"``.
    every : int >= 1, optional
        Default: the scene's ``[output] every`` (1 unless set).  Record every ``every``-th step (and the rest state and the last step), in
        the file and in memory; the effort datasets (Newton iterations, seconds) of
        a recorded state sum the steps since the previous one.
    model : Model, optional
        A model built beforehand (any implementation of the model protocol);
        default: ``voxflex.build.model(scene)``, the model the scene asks for.
    cache : bool
        Frame models load / store their precompute in the on-disk cache
        (:mod:`voxflex.cache`); ``False`` recomputes it.
    force : bool
        Write the result file even over a file that is not a voxflex result or is an input of the run
        (the scene file, its mesh or image); without it those are refused before anything runs, as
        ``voxflex simulate`` refuses them without ``--force`` (one implementation:
        :func:`voxflex.outputs.check_result_output`).
    verbose : bool
        Log the model's size and memory estimate and one line per Newton iteration
        (residual, step length, linear solver and its iterations, seconds) on stderr.

    Returns
    -------
    Result
        Times, probe positions, surface and node states, energies and solver
        statistics for the rest state and every recorded step that ``keep`` holds
        (:attr:`Result.step` numbers them; :meth:`Result.run_totals` sums the whole run).

    Raises
    ------
    InputError
        Bad scene (a label without material, a probe outside the material, loads or constants beyond what
        double precision or a solid carries: :mod:`voxflex.guards`), or an output that would destroy a file.
    ConvergenceError
        The solver did not converge (the message says what was tried).  The steps
        that converged before are written to ``output`` all the same, the file
        marked incomplete (``Result.complete`` False, the message in ``error``).

    Warns
    -----
    InversionWarning
        When samples end a step with det F <= 0 (for a material that cannot recover from inversion, StVK
        or Hooke with the polar corotational strain, naming the materials that can).
    ImplausibleStateWarning
        When a state is more than :data:`voxflex.guards.GROWTH_WARN` times the body's rest size.
    """
    scene = as_scene(scene, "vf.simulate")
    if output is not None and not isinstance(output, (str, os.PathLike)):
        raise InputError(f"output must be a result file path (str or Path), got {type(output).__name__}")
    if model is not None:
        check_model(model)
        from .build import check_built_for

        check_built_for(model, scene)
    from . import _progress
    from ._atomic import atomic_path
    from .build import build_image
    from .build import model as build_model
    from .scene import check_every, check_keep

    from . import guards

    keep = scene.output.keep if keep is None else check_keep(keep)
    every = scene.output.every if every is None else check_every(every)
    target = output if output is not None else scene.output.file
    if target is not None:  # the checks the command line makes, here for the Python API too
        from .outputs import check_result_output, run_inputs

        check_result_output(target, inputs=run_inputs(scene.path, scene), force=force,
                            option="output" if output is not None else "[output] file",
                            hint="pass force=True to overwrite it")
    model_bytes = None
    if model is None:
        from .resources import check as check_resources

        # refuse a scene whose model, kept states or result file cannot fit, before building anything
        est = check_resources(scene, output=target, keep=keep, every=every)
        model_bytes = est.model_bytes
        # the estimate (memory, result file, time) before a long run, or always with verbose
        _progress.announce((est.dofs, f"estimate: {est.summary()}"), force=verbose or (progress and est.seconds >= 60),
                           quiet=not progress)
        image = build_image(scene)
        guards.check_magnitudes(scene, image)
        _progress.announce(image_estimate(image, scene), force=verbose, quiet=not progress)
        t0 = time.perf_counter()
        model = build_model(scene, image=image, cache=cache)
        if verbose:
            _progress.log(f"model built in {time.perf_counter() - t0:.2f} s")
    else:
        image = model.image
        if image is not None:
            guards.check_magnitudes(scene, image)
    _progress.announce(model_estimate(model, scene.solver.steps, model_bytes), force=verbose,
                       quiet=not progress)

    problem = problem_of(scene, model)
    guards.check_held(problem)
    guards.warn_locking(model, scene)
    probe_map = None
    if problem.probes:
        probe_map = model.point_mapping(np.array([point for _, point in problem.probes], dtype=float))

    recorder = _Recorder(scene, problem, image, probe_map, keep=keep, every=every, streamed=target is not None)

    def callback(record):
        if bar is not None:
            bar.update(1)
            bar.set_postfix(newton=record.newton_iterations, refresh=False)

    def newton_callback(info):
        if bar is not None:
            bar.set_postfix(newton=info["iteration"], residual=f"{info['residual']:.1e}")
        if verbose:
            _progress.log(_progress.newton_line(info))

    def run():
        """Solve, the recorder taking every record; the failure (advice added) or None."""
        try:
            # overflow and invalid-value warnings stay inside: Newton rejects non-finite trials, and the
            # recorder refuses every accepted state that is not finite or not plausible (voxflex.guards)
            with np.errstate(all="ignore"):
                # a scene's run starts its model's layers at rest (plastic strains, moving obstacles, a friction
                # lag), whatever an earlier run of the same model left; solve() alone continues from them
                begin_run(model)
                problem.solve(callback=callback,
                              newton_callback=newton_callback if (bar is not None or verbose) else None, sink=recorder)
        except ConvergenceError as exc:
            advice = model.advice()
            failure = ConvergenceError(f"{exc}; note: {advice}" if advice else str(exc))
            if recorder.steps_done < 1 or target is None:
                raise failure from None
            return failure
        return None

    options = problem.options
    bar = _progress.progress(total=options.steps, desc="simulate", unit="step") if progress else None
    try:
        if target is None:
            failure = run()
            recorder.finish()
        else:
            # the states go to a temporary file beside the target as they come; it replaces the target
            # only at the end (an exception, SIGINT or SIGTERM removes it and keeps the old file)
            with atomic_path(target) as tmp:
                recorder.open(tmp)
                try:
                    failure = run()
                    recorder.finish()
                    recorder.close(error=None if failure is None else str(failure))
                finally:
                    recorder.abort()
    except _WriteFailed as exc:  # the temporary file is gone (atomic_path) and the old target untouched
        raise exc.error from None
    finally:
        if bar is not None:
            bar.close()

    result = recorder.result(error=None if failure is None else str(failure))
    if failure is not None:
        raise ConvergenceError(f"{failure}; the {recorder.steps_done} step(s) that converged were written to "
                               f"'{target}', marked incomplete") from None
    recorder.check.warn()
    _warn_inversion(model, recorder)
    _warn_drawn(recorder)
    _warn_tunnel(recorder)
    if recorder.worst_residual[0] > ROUNDOFF_WARN * options.tolerance:
        res, step = recorder.worst_residual
        moved = _prescribed_reach(scene, recorder.surf_rest)
        fix = (f"the fixed regions move the body {moved:.3g} body sizes, so its forces carry eps times that motion: "
               "prescribe a smaller motion, or model it in the body's own frame, for a tighter answer"
               if moved > 1e3 else "soften the stiffness contrast for a tighter answer")
        warnings.warn(
            f"{recorder.roundoff_steps} step(s) stopped at the round-off floor of double precision, far above the "
            f"tolerance {options.tolerance:.1e} (relative residual up to {res:.2e}, step {step}): the stiffest "
            f"parts' forces are known only to about eps |K x|; {fix}",
            RoundoffWarning,
            stacklevel=2,
        )
    return result


def check_model(model) -> None:
    """InputError unless ``model`` has the model protocol's core (:class:`voxflex.deform.models.protocol.Model`)."""
    from .deform.models.protocol import Model

    if not isinstance(model, Model):
        raise InputError(f"model must be a model of the protocol voxflex.deform.models.protocol.Model, such as "
                         f"vf.model(scene), got {type(model).__name__}; to choose the kind of nodes, set the scene's "
                         "[nodes] kind")


def image_estimate(image, scene):
    """(DOFs, text) of the model about to be built on ``image``: the scene's node kind's own estimate
    (:func:`voxflex.resources.estimate_on_image`, the figures the resource check uses)."""
    import numpy as np

    from . import _progress
    from .deform.models.kinds import node_kind
    from .resources import estimate_on_image

    kind = node_kind(scene.nodes.kind)
    voxels = int(np.count_nonzero(np.asarray(image.labels)))
    est = estimate_on_image(scene, image)
    return est.dofs, (f"building {kind.count(est.nodes)} over {voxels} voxels: about {est.dofs} DOF; solve memory "
                      f"about {_progress._megabytes(est.model_bytes)}")


def model_estimate(model, steps: int, model_bytes: float | None = None):
    """(DOFs, text): the model's size and, when known, the memory estimated for its solve."""
    from . import _progress

    dofs = int(model.rest.size)
    samples = model.describe().get("samples")
    text = (f"model: {model.kind.count(model.n_nodes)}, {dofs} DOF"
            + (f", {samples} samples" if samples else "")
            + f"; {steps} step(s)" + ("" if model_bytes is None else f"; memory about {_progress._megabytes(model_bytes)}"))
    return dofs, text


def _prescribed_reach(scene, rest) -> float:
    """How far the fixed regions' transforms move the body's rest surface, in body sizes (0 without one)."""
    rest = np.asarray(rest, dtype=float)
    if rest.size == 0:
        return 0.0
    size = float(np.ptp(rest, axis=0).max()) or 1.0
    reach = 0.0
    for f in getattr(scene, "fixed", ()):
        T = getattr(f, "transform", None)
        if T is None:
            continue
        T = np.asarray(T, dtype=float)
        reach = max(reach, float(np.abs(rest @ T[:, :3].T + T[:, 3] - rest).max()))
    return reach / size


def _warn_tunnel(recorder) -> None:
    """ContactWarning when a sphere or box obstacle passed wholly into the body within a step (tunnelling)."""
    if recorder.tunnel is None:
        return
    from .deform.layers.contact_checks import ContactWarning

    step, which = recorder.tunnel
    names = ", ".join(f"{o} ({recorder.contact.obstacles[o].kind})" for o in which)
    warnings.warn(
        f"obstacle {names} passed into the body at step {step} (its centre is inside the drawn surface, and no "
        "collision point touched it): the step moved the body or the obstacle by more than the obstacle's size, "
        "so the contact stopped acting there; use more steps (or a smaller dt) or a larger obstacle",
        ContactWarning,
        stacklevel=3,
    )


def _warn_drawn(recorder) -> None:
    """ContactWarning when the drawn surface went deeper than DRAWN_TOLERANCE of a voxel into an obstacle the
    collision points do not keep it out of (a box's or a distance field's edges between the vertices)."""
    depth, step, o = recorder.drawn
    image = recorder.image
    h = float(np.min(image.spacing)) if image is not None else None
    from .deform.layers.contact_checks import DRAWN_TOLERANCE, ContactWarning

    if o < 0 or h is None or depth <= DRAWN_TOLERANCE * h:
        return
    ob = recorder.contact.obstacles[o]
    warnings.warn(
        f"the drawn surface entered obstacle {o} ({ob.kind}) by {depth:.3g} m ({depth / h:.1%} of a voxel) at step "
        f"{step}: its edges and corners cross the triangles between the collision points, which stay out; use a "
        f"finer voxel_size (the depth scales with it)"
        f"{', or a plane or sphere where one fits' if ob.kind == 'box' else ''}",
        ContactWarning,
        stacklevel=3,
    )


def _warn_inversion(model, recorder) -> None:
    """InversionWarning when samples inverted after some step: naming the materials that cannot recover, or
    (any other material) saying that the state is not physical."""
    if recorder.first_inverted is None:
        return
    bad = sorted({m.name for m in model.materials.values() if _cannot_recover(m)})
    step, count = recorder.first_inverted
    if not bad:
        warnings.warn(
            f"{count} samples inverted (det F <= 0; min det F {recorder.totals['min_det_F']:.3g}) from step {step} on: "
            "such a state is not physical (with linear strain the load is far beyond small strains); use smaller "
            "loads, more steps, or a finite-strain material such as \"stable-neo-hookean\"",
            InversionWarning,
            stacklevel=3,
        )
        return
    warnings.warn(
        f"{count} samples inverted (det F <= 0; min det F {recorder.totals['min_det_F']:.3g}) from step {step} on, "
        f"with {', '.join(bad)}, a material that cannot recover from inversion; use model = \"stable-neo-hookean\" "
        "or strain = \"corotational-svd\"",
        InversionWarning,
        stacklevel=3,
    )


class _Recorder:
    """The solver's sink: turns every StepRecord into the result's per-state rows.

    Per step it updates the run's totals (Newton iterations, seconds, inversion) and,
    for a recorded step (the rest state, every ``every``-th step, the last one),
    computes the row (time, probes, surface and node state, energies, effort since
    the previous recorded state, inversion, fields, reactions, contact forces,
    cable tensions), appends it to the result file when one is open and holds it
    when ``keep`` asks.  Memory held whatever the number of steps: the previous
    record (the reactions' inertia term), the latest unrecorded one, the rest row,
    the rows ``keep`` holds, the file writer's buffer (about 4 MiB) and the totals.
    """

    def __init__(self, scene, problem, image, probe_map, *, keep, every, streamed):
        from .deform.layers.cables import CableModel
        from .deform.layers.contact import ContactModel
        from .deform.layers.contact_checks import drawn_depth, tunnelled
        from .deform.layers.plasticity import PlasticModel

        model, options = problem.model, problem.options
        self.scene, self.problem, self.image, self.model, self.probe_map = scene, problem, image, model, probe_map
        self._layer = None  # (q, model.sample_fields(q)) of the state being recorded
        self.surf_rest, self.faces, self.surf_map = model.boundary_surface()
        names = scene.output.fields
        self.names = names
        self.cell_fields = any(n != "reaction" for n in names)
        self.reactions = _Reactions(problem) if "reaction" in names and problem.fixed else None
        self.contact = _layer(model, ContactModel)
        self.cables = _layer(model, CableModel)
        self.plastic = _layer(model, PlasticModel)
        self.steps = int(options.steps)
        self.every = int(every)
        self.keep = keep
        self.streamed = bool(streamed)
        self.location = ""
        self.writer = None
        self.path = None
        self.rest_row = None
        self.kept = None
        self.count = 0  # records seen (the rest state is record 0)
        self.prev = None  # the previous step's record
        self.held = None  # the latest step's (step, record, previous record, inversion) when it was not recorded
        self.effort = [0, 0.0]  # Newton iterations and seconds since the last recorded state
        self.totals = {"steps": 0, "newton_iterations": 0, "step_seconds": 0.0, "inverted_samples": 0,
                       "min_det_F": float("inf"), "min_det_F_step": 0}
        self.first_inverted = None  # (step, count) of the first step with inverted samples
        self.worst_residual = (0.0, 0)  # (largest relative residual a step was accepted at, its step)
        self.roundoff_steps = 0  # steps accepted at the round-off floor, above options.tolerance
        self.tolerance = float(options.tolerance)
        from .guards import StateCheck

        self.check = StateCheck(self.surf_rest)  # every accepted state: finite, in balance, of plausible size
        # how deep the drawn triangles went into the obstacles the barrier does not keep them out of (a box's
        # edges between the vertices): (depth m, step, obstacle), measured at every accepted step
        self.drawn = (0.0, 0, -1)
        self._drawn_check = self.contact is not None and any(
            ob.kind not in self.contact.kept_out for ob in self.contact.obstacles) and len(self.faces) > 0
        # the first step at which a sphere or box obstacle was found wholly inside the body: (step, [obstacles])
        self.tunnel = None
        self._drawn_depth, self._tunnelled = drawn_depth, tunnelled
        self._tunnel_check = self.contact is not None and len(self.faces) > 0 and any(
            ob.kind in ("sphere", "box") for ob in self.contact.obstacles)
        self._surface = None  # (q, drawn surface positions) of the state being recorded

    @property
    def steps_done(self) -> int:
        """Steps converged so far."""
        return max(self.count - 1, 0)

    # -- the sink ---------------------------------------------------------
    def __call__(self, rec) -> None:
        from ._atomic import check_interrupted

        k = self.count
        q = np.asarray(rec.q, dtype=float)
        self.check.state(k, q, float(rec.residual) if k > 0 else 0.0, rec.displacement)
        surface = self.surf_map.apply(q)
        self._surface = (rec.q, surface)
        self.check.size(k, surface)
        if k > 0 and (self._drawn_check or (self._tunnel_check and self.tunnel is None)):
            fraction = self.problem.fraction(float(rec.time))  # where moving obstacles stand at this state
            if self._drawn_check:
                depth, which = self._drawn_depth(self.contact.obstacles, surface, self.faces, fraction,
                                                 self.contact.kept_out)
                if depth > self.drawn[0]:
                    self.drawn = (depth, k, which)
            if self._tunnel_check and self.tunnel is None:
                inside = self._tunnelled(self.contact.obstacles, surface, self.faces, fraction)
                if inside:
                    self.tunnel = (k, inside)
        self.count += 1
        inversion, location = self._inversion(rec.q)
        self.location = location
        t = self.totals
        t["steps"] = k
        t["newton_iterations"] += int(rec.newton_iterations)
        t["step_seconds"] += float(rec.seconds)
        t["inverted_samples"] = max(t["inverted_samples"], inversion[0])
        if inversion[1] < t["min_det_F"]:
            t["min_det_F"], t["min_det_F_step"] = inversion[1], k
        if inversion[0] > 0 and self.first_inverted is None:
            self.first_inverted = (k, inversion[0])
        if k > 0 and rec.residual > self.worst_residual[0]:
            self.worst_residual = (float(rec.residual), k)
        self.roundoff_steps += int(k > 0 and rec.residual > ROUNDOFF_WARN * self.tolerance)
        self.effort[0] += int(rec.newton_iterations)
        self.effort[1] += float(rec.seconds)
        if k == 0 or k % self.every == 0 or k == self.steps:
            self._record(k, rec, self.prev, inversion)
            self.held = None
        else:
            self.held = (k, rec, self.prev, inversion)
        self.prev = rec
        self._layer = None  # a held step (every > 1) recomputes its fields if it is recorded later
        check_interrupted()  # SIGINT / SIGTERM during a streamed run: stop after this step, file discarded

    def finish(self) -> None:
        """Record the last converged step when ``every`` skipped it (a run that stopped early)."""
        if self.held is not None:
            self._record(*self.held)
            self.held = None

    # -- the file ---------------------------------------------------------
    def open(self, path) -> None:
        """Stream the rows to ``path`` (a temporary file; the writer is created at the first row)."""
        self.path = path

    def close(self, *, error=None) -> None:
        """Finish the file: the buffered rows, ``complete`` / ``error`` and the totals."""
        if self.writer is not None:
            with _writing(self):
                self.writer.close(complete=error is None, error=error or "", totals=self._totals())

    def abort(self) -> None:
        if self.writer is not None:
            try:
                self.writer.abort()
            except Exception as exc:  # noqa: BLE001 - cleanup after a failed write: the file is discarded anyway
                if not _io_failure(exc):
                    raise

    # -- rows -------------------------------------------------------------
    def _inversion(self, q):
        """((samples with det F <= 0, smallest det F), cell kind) at state ``q``."""
        from .deform.materials.fbar import _det3

        layer = self.model.sample_fields(q)
        self._layer = (q, layer)  # the fields of this state reuse it (the row is built next, for the same q)
        det = _det3(np.asarray(layer["F"], dtype=float))  # by cofactors: a fifth of LAPACK's batched LU
        return (int(np.count_nonzero(~(det > 0))), float(np.min(det)) if len(det) else 1.0), layer["cell_kind"]

    def _row(self, k, rec, prev, inversion) -> dict:
        from .deform.models.fields import model_fields
        from .deform.models.protocol import DisplacementMap

        q = np.asarray(rec.q, dtype=float)
        row = {"time": float(rec.time)}
        if self.probe_map is not None:
            positions = self.probe_map.apply(q)
            moved = None
            if isinstance(self.probe_map, DisplacementMap) and self.probe_map.linear:
                # the probes' displacement from the solver's q - X (its digits kept)
                u = rec.displacement if rec.displacement is not None else q - np.asarray(self.model.rest, dtype=float)
                moved = self.probe_map.jvp(self.model.rest, np.asarray(u, dtype=float))
            for i, (name, _) in enumerate(self.problem.probes):
                row[f"probes/{name}"] = positions[i]
                if moved is not None:
                    row[f"probe_displacements/{name}"] = moved[i]
        drawn = self._surface
        row["surface/positions"] = drawn[1] if drawn is not None and drawn[0] is rec.q else self.surf_map.apply(q)
        row["nodes/state"] = q
        row["energy/elastic"] = float(rec.elastic_energy)
        row["energy/kinetic"] = float(rec.kinetic_energy)
        row["stats/newton_iterations"] = self.effort[0]
        row["stats/step_seconds"] = self.effort[1]
        row["stats/step"] = k
        row["stats/inverted_samples"], row["stats/min_det_F"] = inversion
        if self.cell_fields:
            layer = self._layer
            sample = layer[1] if layer is not None and layer[0] is rec.q else None
            cells, surface = model_fields(self.model, q, self.names, sample=sample)
            row.update({f"fields/{name}": v for name, v in cells.items()})
            row.update({f"surface/fields/{name}": v for name, v in surface.items()})
        if self.reactions is not None:
            row["reactions/force"] = self.reactions(rec, prev)
        fraction = self.problem.fraction(float(rec.time))
        row["stats/fraction"] = fraction
        points = self.model.node_points(q)
        if points is not None:
            row["nodes/points"] = np.asarray(points, dtype=float)
        if self.contact is not None:
            row["contact/force"] = self.contact.contact_forces(q, fraction=fraction)
        if self.cables is not None:
            row["cable/tension"] = self.cables.tensions(q, fraction=fraction)
            row["cable/points"] = _cable_points(self.cables, q)
        if self.plastic is not None:  # the sink runs after the step's plastic state is committed: it is this state's
            row["plasticity/yielded_samples"], row["plasticity/max_strain"] = self.plastic.measure()
        return row

    def _record(self, k, rec, prev, inversion) -> None:
        row = self._row(k, rec, prev, inversion)
        self.effort = [0, 0.0]
        if self.rest_row is None:
            self.rest_row = row
            self._start(row)
        elif self.kept is not None:
            self.kept.append(row)
        if self.path is not None:
            with _writing(self):
                if self.writer is None:
                    from .result import ResultWriter

                    self.writer = ResultWriter(self.path, self._static())
                self.writer.append(row)

    def _start(self, row) -> None:
        """Decide what the rest of the run holds in memory (``keep``), from the size of the rest state's row."""
        from collections import deque

        keep = self.keep
        if keep == "auto":
            nbytes = sum(np.asarray(v).nbytes for v in row.values())
            recorded = self.steps // self.every + 1
            keep = "all" if not self.streamed or recorded * nbytes <= AUTO_KEEP_BYTES else "last"
        self.kept = [] if keep == "all" else deque(maxlen=1 if keep == "last" else int(keep))

    def _static(self) -> dict:
        image, model = self.image, self.model
        return dict(
            version=__version__, scene=self.scene.to_toml(), node_kind=model.kind.name,
            model={**model.describe(), "nodes": model.kind.plural}, problem=self.problem.record(),
            surface_rest=self.surf_rest, surface_faces=self.faces, nodes_rest=np.asarray(model.rest, dtype=float),
            image_labels=image.labels, image_spacing=image.spacing, image_origin=image.origin,
            image_direction=image.direction, cell_location=self.location if self.cell_fields else "",
            cable_point_cable=None if self.cables is None else _cable_point_owner(self.cables),
        )

    def _totals(self) -> dict:
        t = dict(self.totals)
        if not np.isfinite(t["min_det_F"]):
            t["min_det_F"] = 1.0
        return t

    def result(self, *, error=None) -> Result:
        """The Result of the rows held (the rest state and what ``keep`` kept)."""
        from .result import series_of

        rows = [self.rest_row, *(self.kept or ())]
        stacked = {key: np.stack([np.asarray(r[key]) for r in rows]) for key in rows[0]}
        return Result(**self._static(), **series_of(stacked), totals=self._totals(),
                      complete=error is None, error=error or "")


class _WriteFailed(Exception):
    """The result file could not be written (a full disk, a vanished folder): carries the one-line
    :class:`~voxflex.errors.VoxflexError` the run ends with, past the solver's own error handling."""

    def __init__(self, error):
        super().__init__(str(error))
        self.error = error


def _io_failure(exc) -> bool:
    """An OSError, or h5py's RuntimeError for a failed write (its message carries the system's errno)."""
    if isinstance(exc, OSError):
        return True
    text = str(exc)
    return isinstance(exc, RuntimeError) and ("errno =" in text or "write failed" in text)


class _writing:
    """Turns an OSError of the result writer into :class:`_WriteFailed` naming the file, the step and the cause."""

    def __init__(self, recorder):
        self.recorder = recorder

    def __enter__(self):
        return self

    def __exit__(self, kind, exc, tb):
        if exc is None or not _io_failure(exc):
            return False
        import errno

        from .errors import VoxflexError

        code = getattr(exc, "errno", None)
        text = str(exc)
        full = code in (errno.ENOSPC, errno.EDQUOT) or "No space left" in text or "errno = 28" in text
        cause = "the disk is full" if full else f"{type(exc).__name__}: {text.splitlines()[0] if text else ''}"
        fix = "free disk space, record fewer states (--every K) or write elsewhere" if full else "write elsewhere"
        raise _WriteFailed(VoxflexError(
            f"writing the result failed after step {self.recorder.steps_done} ({cause}); nothing was replaced and "
            f"no partial file remains; {fix}")) from None


class _Reactions:
    """Total force each fixed region exerts on the body at a state (R, 3).

    At the held DOFs the support's force on the body balances the rest:
    ``R = dE/dq - f`` (statics, ``f`` at the state's load factor) plus the
    inertia ``M (v_k - v_{k-1}) / h`` and damping ``D v_k`` terms of implicit Euler
    (D with the stiffness at the step's start, as the solver has it).  Each region's total is the
    virtual work of R on its DOFs under a unit translation of the body, so
    affine frames count their translation DOFs.
    """

    def __init__(self, problem):
        model, options = problem.model, problem.options
        self.model, self.options, self.n = model, options, len(problem.fixed)
        self.dofs, self.owner = problem.held
        rest = np.asarray(model.rest, dtype=float)
        self.f = problem.loads
        modes = []
        for k in range(3):
            T = np.hstack([np.eye(3), np.eye(3)[:, [k]]])
            modes.append((model.moved_state(T) - rest).ravel()[self.dofs])
        self.modes = np.stack(modes, axis=1)  # (k, 3)
        self.dynamic = problem.dynamic
        self.M = problem.mass

    def __call__(self, rec, prev) -> np.ndarray:
        """(R, 3) at the state of ``rec``; ``prev`` is the previous step's record (None at the rest state)."""
        options, M = self.options, self.M
        q = np.asarray(rec.q, dtype=float)
        g = self.model.gradient(q).ravel()
        if self.dynamic:
            g = g - self.f
            if prev is not None:
                v1, v0 = np.ravel(rec.v), np.ravel(prev.v)
                g = g + M @ ((v1 - v0) / options.dt)
                if options.rayleigh_mass or options.rayleigh_stiffness:
                    g = g + options.rayleigh_mass * (M @ v1)
                    if options.rayleigh_stiffness:
                        K0 = self.model.hessian(np.asarray(prev.q, dtype=float))
                        g = g + options.rayleigh_stiffness * (K0 @ v1)
        else:
            g = g - rec.time * self.f
        work = g[self.dofs, None] * self.modes
        out = np.zeros((self.n, 3))
        for r in range(self.n):
            out[r] = work[self.owner == r].sum(axis=0)
        return out


def _layer(model, cls):
    """The layer of type ``cls`` in a stack of wrapped models (``.inner`` after ``.inner``), or None."""
    while model is not None:
        if isinstance(model, cls):
            return model
        model = model.__dict__.get("inner")
    return None


def _cable_point_owner(layer) -> np.ndarray:
    """(P,) the cable of each row of :func:`_cable_points`: every cable's anchor (if any), then its points."""
    owner = []
    for i, c in enumerate(layer.cables):
        owner += [i] * (len(c.points) + (c.anchor is not None))
    return np.array(owner, dtype=np.int64)


def _cable_points(layer, q) -> np.ndarray:
    """(P, 3) every cable's anchor (if any) then its points mapped at state q: the polylines renders draw."""
    owner = np.repeat(np.arange(len(layer.cables)), [len(c.points) for c in layer.cables])
    x = layer.mapping.apply(q)
    rows = []
    for i, c in enumerate(layer.cables):
        if c.anchor is not None:
            rows.append(np.asarray(c.anchor, dtype=float)[None])
        rows.append(x[owner == i])
    return np.vstack(rows)
