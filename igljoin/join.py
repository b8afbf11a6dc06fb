"""Join a flexible guest to a rigid host: ``JoinSolver`` and ``join()``.

The steps follow the paper: select the boundary curves (§3), map them onto
each other and insert host points into the guest (§4.1), build the shape,
stretch and smooth-join terms (§4.2–4.4) and minimise them under the hard
seam constraints by a local/global iteration (§4.5).

Several seams (``seams=[(host_curve, guest_curve), ...]``) are joined in one
solve: the correspondence runs seam after seam on the progressively refined
guest, each seam gets its own smooth-join term, and all seam vertices are
the fixed vertices of one factorization.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from functools import partial
from typing import Any

import numpy as np

from . import seams as seams_
from .correspond import rigid_fit
from .errors import OptionsError
from .host_values import HostValues
from .join_terms import TermInputs, build_terms, seam_bands
from .measure_join import RestMeasures, join_result
from .mesh import Mesh, as_mesh
from .options import JoinOptions
from .result import JoinResult
from .seams import SeamPair
from .solve import LocalGlobalSolver, QuasiNewtonMemory
from .start import bulge, bulge_basis, path_prediction, rigid_start
from .stiffness import needs_guest, resolve_stiffness
from .terms import unique_edges
from .twolevel import preferred_model
from .validate import check_surface

__all__ = ["JoinSolver", "JoinResult", "SeamPair", "SolveProgress", "join"]

#: Marks a value of the set-up not made yet (``None`` is a value).
_UNSET = object()

# options that change the quadratic form (and so need a new factorization)
_STRUCTURAL = JoinOptions.structural_fields()

#: A host with more faces than this is checked near its curves only
#: (:func:`igljoin.seams.host_neighbourhood`).
HOST_CHECK_ALL_FACES = 200_000

#: Earlier results a re-solve along a path of re-solves predicts its start from
#: (:func:`igljoin.start.path_prediction`). One: the move from the result before,
#: carried on (first order). Two would be second order on a slider's even steps, but
#: it amplifies each result's own convergence error (within the tolerance, not zero)
#: three times over, and along a long drag those errors grew: 30 steps of 0.5° on the
#: paper samples took 506-802 iterations in all with two against 309-374 with one.
PATH_LENGTH = 1

#: Converged results a solver keeps, each with the results of the path that led to it,
#: so that a re-solve from any of them finds its path: a solve in between (e.g. a cold
#: solve for comparison) does not cut the path it is not on.
KEPT_RESULTS = 4

#: Kept results on a path whose run's quasi-Newton pairs are kept too, the newest: two,
#: so that the step from the result before the newest can be solved again with the
#: same pairs (the same result, to the bit).
PAIRS_KEPT = 2

#: Bytes of one run's quasi-Newton pairs up to which they are kept: 2 (acceleration + 1)
#: 3n' floats, 53 MB at 100k guest vertices with the default acceleration, 0.5 GB at 1M,
#: where a path's re-solves start without them rather than hold twice that.
PAIRS_MAX_BYTES = 1 << 28


@dataclass(frozen=True)
class _Kept:
    """A converged result the solver keeps: where a path of re-solves may continue.

    Attributes
    ----------
    X : ndarray, shape (n', 3)
        Its guest positions (a copy).
    earlier : tuple of ndarray
        The results of the path before it, oldest first (at most ``PATH_LENGTH``;
        none for a solve from the initial guess).
    memory : QuasiNewtonMemory or None
        Its run's quasi-Newton pairs, kept for a result on a path (``earlier``
        not empty): the next re-solve along the path starts with them.
    rotations : ndarray, shape (n', 3, 3), or None
        The rotations its run's last local step fitted, kept for a result on
        a path (9n' floats, whatever becomes of the pairs): the next re-solve's
        first rotation fit starts from them, turned as the seam turns from
        this result onto the new targets.
    """

    X: np.ndarray
    earlier: tuple
    memory: QuasiNewtonMemory | None
    rotations: np.ndarray | None


def _guest_mesh(guest: Any) -> Mesh:
    """The guest as a :class:`Mesh` named "guest" (attributes kept)."""
    mesh = as_mesh(guest, "guest")
    if mesh.name == "mesh":
        mesh = Mesh(mesh.V, mesh.F, mesh.vertex_attributes, mesh.face_attributes, name="guest")
    return mesh


@dataclass(frozen=True)
class SolveProgress:
    """State of a running solve, passed to the ``progress`` callable after every iteration.

    Attributes
    ----------
    iteration : int
        Iterations done (1, 2, ...).
    max_iterations : int
        The solve stops at this count at the latest.
    energy : float
        Energy after this iteration.
    elapsed : float
        Seconds since the iteration started (after setup and factorization).
    """

    iteration: int
    max_iterations: int
    energy: float
    elapsed: float


def _check_progress(progress: Any) -> None:
    if progress is not None and not callable(progress):
        raise OptionsError(
            f"progress={progress!r} must be a callable taking an igljoin.SolveProgress (or None)"
        )


class JoinSolver:
    """Prepare a join once; solve it, and re-solve cheaply.

    Parameters
    ----------
    host : Mesh or (V, F), or list of them
        The rigid host: one mesh (possibly of several components), or a
        list of meshes, which are joined as one host whose vertices are
        those of the meshes in order (``JoinResult.host_offsets``).
    guest : Mesh or (V, F)
        The flexible guest.
    host_curve, guest_curve : None, Curve, mapping, int or array_like of int
        The boundary curves of a single seam (see :class:`igljoin.Curve`).
        ``None`` takes the only boundary loop; for a closed guest curve
        without a start, the start is found by fitting the curves rigidly.
        Not together with ``seams``.
    options : JoinOptions or dict, optional
    seams : list of tuple, optional
        Several seams joined in one solve, each ``(host_curve, guest_curve)``
        or ``(host_index, host_curve, guest_curve)``. With ``host_index``
        the host curve is selected on ``host[host_index]`` (its own vertex
        indices and loops); without it, on the combined host (vertex
        indices of the concatenated hosts). Seams may not share a vertex,
        on the host or on the guest. ``seams=[(hc, gc)]`` is the same as
        ``host_curve=hc, guest_curve=gc``.
    stiffness_regions : list of (vertex_indices, k), optional
        Relative stiffness ``k`` of regions of guest vertices (1 elsewhere),
        see :func:`igljoin.stiffness_from_regions`. Not together with
        ``stiffness``.
    **overrides
        Individual options (see :class:`igljoin.JoinOptions`). ``stiffness``
        may also name a per-vertex or per-face attribute of the guest
        (``stiffness="name"``).

    Attributes
    ----------
    host : Mesh
        The (combined) host.
    hosts : list of Mesh
        The host meshes as given (one for a single mesh).
    guest : Mesh
    pairs : list of SeamPair
        The resolved curves of each seam.
    host_curve, guest_curve : SelectedCurve or None
        The curves of a single seam (``None`` with several; see ``pairs``).
    corr : Correspondence
        Of all seams together (see ``JoinResult.correspondence``).
    host_values : HostValues
        The rigid host's values along its curves (band fits, one-ring inward
        directions, dihedral angles), made once and kept for every solve.

    Notes
    -----
    The factorization of the quadratic form is kept: :meth:`solve` with new
    seam targets or iteration settings reuses it; changing a weight or the
    smooth term rebuilds it (:attr:`factorizations` counts them).
    ``solve(targets, start=previous_result)`` also starts from the previous
    result, which after a small change of the targets needs fewer
    iterations. Along a path of such re-solves (a slider: each solved from
    the result before) the solver predicts the next start from the path's
    moves (:meth:`warm_start`) and starts the iteration with the
    quasi-Newton pairs of the step before (the curvature it measured near
    the minimum). It keeps its last ``KEPT_RESULTS`` (4) converged results,
    copies of the guest positions, each with the result of the path before
    it (so a solve in between, e.g. a cold one, does not cut a path), and
    the quasi-Newton pairs of the newest ``PAIRS_KEPT`` (2) results on a
    path (2 × (acceleration + 1) × 3n' floats each, kept up to
    ``PAIRS_MAX_BYTES``, 256 MiB), and for every result on a path the
    rotations its last local step fitted (9n' floats; the next step's first
    rotation fit starts from them, turned as the seam turns onto the new
    targets); an option change that
    rebuilds the factorization forgets them, a change of the iteration
    settings does not (it leaves the minima where they are).

    The coarse model of ``preconditioner="auto"`` (large guests) or
    ``"two-level"`` is kept too (:attr:`last_model`): the next solve reuses
    its clusters and patterns, and its factorization unless the new start
    has turned from where it was last built (then it is rebuilt there;
    :func:`igljoin.twolevel.preferred_model`). A new set-up, another
    preconditioner or ``acceleration=0`` drops it; so does a solve whose
    model was refused or failed, and a model whose coarse system could not
    be factored soundly is not kept (the next solve makes a new one).

    A host of more than ``HOST_CHECK_ALL_FACES`` (200,000) faces whose
    curves are given by vertex indices is checked, selected and measured
    near its curves only (docs/limits.md, *Large hosts*).

    Examples
    --------
    >>> import igljoin
    >>> s = igljoin.phantoms.paper_sample("partial_patch", "equal", resolution=0.4)
    >>> solver = igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve)
    >>> res = solver.solve()
    >>> bool(res.metrics["seam_gap"]["relative_max"] < 1e-9)
    True
    """

    def __init__(
        self,
        host: Any,
        guest: Any,
        host_curve: Any = None,
        guest_curve: Any = None,
        options: JoinOptions | dict | None = None,
        *,
        seams: Any = None,
        stiffness_regions: Any = None,
        **overrides: Any,
    ):
        t0 = time.perf_counter()
        guest_mesh = None
        if needs_guest(options, overrides, stiffness_regions):
            guest_mesh = _guest_mesh(guest)
            overrides = resolve_stiffness(guest_mesh, options, overrides, stiffness_regions)
        self.options = JoinOptions.make(options, **overrides)
        # §3: the hosts, and the curves of every seam selected and paired
        self.hosts, self.host, self.host_offsets, several = seams_.load_hosts(host)
        self.guest = _guest_mesh(guest) if guest_mesh is None else guest_mesh
        self._host_near = (
            None
            if several
            else seams_.host_neighbourhood(self.host, host_curve, seams, HOST_CHECK_ALL_FACES)
        )
        if several:
            for h in self.hosts:
                check_surface(h, h.name)
        else:
            seams_.check_host(self.host, self._host_near)
        check_surface(self.guest, "guest")
        self.pairs = seams_.select_seams(
            self.hosts, self.host, self.host_offsets, self._host_near, self.guest,
            host_curve, guest_curve, seams, several,
        )  # fmt: skip
        single = len(self.pairs) == 1
        self.host_curve = self.pairs[0].host_curve if single else None
        self.guest_curve = self.pairs[0].guest_curve if single else None
        self.pairing = self.pairs[0].pairing if single else {}
        # the rigid host's values along its curves, made once for every set-up and solve
        self.host_values = HostValues(self.host, self._host_near)
        self.factorizations = 0
        self.last_run = None  # IterationResult of the latest solve (iteration statistics)
        # the latest solve's coarse model (igljoin.twolevel.TwoLevelModel), None for P alone;
        # its ``fallback`` says why "auto" kept P where the model would not fit. The next
        # solve continues with it while the set-up and the preconditioner stand (its
        # built_at and seconds then run on across the solves)
        self.last_model = None
        self.timings: dict[str, float] = {"select": time.perf_counter() - t0}
        self._prepare()

    # -- set-up -----------------------------------------------------------------------------

    def _prepare(self) -> None:
        """Set up the correspondence, terms and factorization for the current options.

        Everything is made first and only then kept, so a set-up that fails
        (a size guard, a system that cannot be factored) leaves the solver as
        it was.
        """
        t0 = time.perf_counter()
        opt, host = self.options, self.host
        # §4.1: the curves mapped onto each other, host points inserted into the guest
        parts, c = seams_.correspond_seams(
            self.guest.V, self.guest.F, host.V, self.pairs, opt.snap_fraction
        )
        t1 = time.perf_counter()
        E = unique_edges(c.F)
        # the rest guest's measures (see join_result); its band fits serve the terms too,
        # which keep none of their own
        rest = RestMeasures(c, E)
        # §4.2–4.4: shape, stretch and one smooth-join term per seam
        curves = [p.host_curve for p in self.pairs]
        bands = seam_bands(opt, host, c, curves, parts)
        # the band fits the measures will use (kept), made now: a band too large for its
        # fit is refused here, not after a solve
        for curve, part, band in zip(curves, parts, bands):
            self.host_values.band_fit(curve, band)
            rest.fit(part.seam[part.host_hit], curve.closed, band)
        built = build_terms(
            TermInputs(
                opt, c, E, self.guest, host, self.host_values, curves, parts, bands,
                partial(rest.fit, keep=False),
            )
        )  # fmt: skip
        t2 = time.perf_counter()
        # §4.5: the seam vertices fixed in one factorization
        solver = LocalGlobalSolver(built.terms, len(c.V), c.seam, opt.linear_solver)
        self.parts, self.corr, self.E, self._rest, self.bands = parts, c, E, rest, bands
        self.guest_mean_edge = float(rest.edge_lengths.mean())
        self.built, self.terms, self.solver = built, built.terms, solver
        self.factorizations += 1
        # made on a solve's first use (see _bumped, initial_guess) and kept until the next set-up
        self._bump = None
        self._bulge_basis: Any = _UNSET
        # the coarse model (twolevel.preferred_model) kept for the next solve on this set-up
        self._model = None
        self._forget_path()
        self.timings.update(correspond=t1 - t0, terms=t2 - t1, factor=solver.factor_seconds)

    # -- solving ----------------------------------------------------------------------------

    def update(self, *, stiffness_regions: Any = None, **changes: Any) -> None:
        """Change options; the factorization is rebuilt only if the quadratic form changes.

        ``stiffness`` may name a guest attribute, and ``stiffness_regions``
        replaces the stiffness map, as in the constructor. A change refused
        by the set-up (e.g. a band too large for its fit) leaves the solver
        as it was: its options, correspondence and factorization.
        """
        if needs_guest(None, changes, stiffness_regions):
            changes = resolve_stiffness(self.guest, None, changes, stiffness_regions)
        new = self.options.replace(**changes)
        old = self.options
        self.options = new
        structural = any(not _same(getattr(old, name), getattr(new, name)) for name in _STRUCTURAL)
        if structural:
            try:
                self._prepare()
            except BaseException:
                # the set-up keeps nothing until it is whole: the old options still fit it
                self.options = old
                raise

    def initial_guess(self, targets: np.ndarray | None = None) -> np.ndarray:
        """Rigidly aligned rest guest, with the seam displacement smoothly extended.

        One rigid motion fits all seam vertices (of every seam) onto their
        targets; the remaining seam displacement is then extended smoothly
        (``Q u = 0`` on the free vertices), so a guest whose ends go to two
        different places starts bent towards both.

        Returns shape (n', 3).
        """
        c = self.corr
        bc = c.targets if targets is None else targets
        X = rigid_start(c.V, c.seam, bc)
        if self.options.initial_guess == "extend":
            X = X + self.solver.extend(bc - X[c.seam])
            # a compressed disk-like guest bulges instead of shrinking
            if self._bulge_basis is _UNSET:
                self._bulge_basis = bulge_basis(c.V, c.F, c.seam, self.host, self.host_curve)
            X = bulge(X, c.F, self._bulge_basis, self._bumped)
        return X

    def _bumped(self) -> np.ndarray:
        """The factorization's response to a unit load (``LocalGlobalSolver.bump``), made once."""
        if self._bump is None:
            self._bump = self.solver.bump()
        return self._bump

    def warm_start(self, start: Any, targets: np.ndarray) -> np.ndarray:
        """Positions ``start`` moved onto the seam ``targets``: where a re-solve starts.

        ``start`` is first carried on along the path of re-solves that led
        to it, if it is the latest result of such a path (each solved from
        the one before by this solver, within one set-up):
        the earlier results' own moves predict the guest's response to the
        new targets (:func:`igljoin.start.path_prediction`). Then the rigid
        motion that best fits its seam onto the targets moves it, and the
        remaining seam move is extended smoothly, as for
        :meth:`initial_guess`.

        Parameters
        ----------
        start : ndarray, shape (n', 3), or JoinResult
            Positions of the refined guest (``JoinResult.guest.V`` of an
            earlier solve of this solver, or the result itself).
        targets : ndarray, shape (s, 3)

        Returns
        -------
        ndarray, shape (n', 3)
        """
        X = self._start_positions(start)
        return self._warm_start(X, targets, self._kept_at(X))

    def _warm_start(self, X: np.ndarray, targets: np.ndarray, kept: _Kept | None) -> np.ndarray:
        """:meth:`warm_start` from checked positions ``X`` (n', 3), kept as ``kept`` (or not)."""
        seam = self.corr.seam
        X = path_prediction(X, [] if kept is None else list(kept.earlier), seam, targets)
        X = rigid_start(X, seam, targets)
        return X + self.solver.extend(targets - X[seam])

    def _start_positions(self, start: Any) -> np.ndarray:
        """``start`` as a checked (n', 3) array of positions (a copy)."""
        if isinstance(start, JoinResult):
            start = start.guest.V
        n = len(self.corr.V)
        try:
            X = np.array(start, dtype=np.float64)
        except (TypeError, ValueError):
            X = None
        if X is None or X.shape != (n, 3) or not np.isfinite(X).all():
            raise OptionsError(
                f"start must be a finite array of shape ({n}, 3) (the refined guest's positions, "
                "e.g. an earlier result's guest.V) or a JoinResult of this solver"
            )
        return X

    # -- the path of re-solves (what warm_start predicts from) -----------------------------

    def _forget_path(self) -> None:
        # the latest converged results, oldest first (at most KEPT_RESULTS)
        self._kept: list[_Kept] = []

    def _kept_at(self, X: np.ndarray) -> _Kept | None:
        """The kept result at positions ``X`` (n', 3), the latest if several; ``None``."""
        for kept in reversed(self._kept):
            if np.array_equal(X, kept.X):
                return kept
        return None

    def _keep(self, before: _Kept | None, run: Any, X: np.ndarray) -> None:
        """Keep the result ``X`` of a solve from the kept result ``before`` (``None``: from
        the initial guess or from positions not kept)."""
        if not run.converged:
            return  # not a minimum: nothing to predict from
        earlier = () if before is None else (*before.earlier, before.X)[-PATH_LENGTH:]
        memory = run.memory if earlier else None
        rotations = run.rotations if earlier else None
        kept = [*self._kept, _Kept(np.array(X, dtype=np.float64), earlier, memory, rotations)]
        # the pairs are large (2 (acceleration + 1) 3n' floats): the newest PAIRS_KEPT only
        holding = [i for i, k in enumerate(kept) if k.memory is not None][:-PAIRS_KEPT]
        for i in holding:
            kept[i] = replace(kept[i], memory=None)
        self._kept = kept[-KEPT_RESULTS:]

    def solve(
        self,
        targets: np.ndarray | None = None,
        *,
        progress: Any = None,
        start: Any = None,
        **changes: Any,
    ) -> JoinResult:
        """Deform the guest.

        Parameters
        ----------
        targets : ndarray, shape (s, 3), optional
            New positions for the seam vertices, in the order of
            ``JoinResult.seam`` (seam after seam; default: the host curve
            correspondence). Reuses the factorization.
        start : ndarray, shape (n', 3), or JoinResult, optional
            Start the iteration from these positions of the refined guest
            (e.g. the previous result, for a re-solve after a small change
            of the targets) instead of :meth:`initial_guess`; the seam is
            moved onto the targets rigidly and the rest of the move extended
            smoothly, after a prediction from the earlier results when the
            start ends a path of re-solves (:meth:`warm_start`; the
            iteration then also starts with the quasi-Newton pairs and the
            rotations of the step before). A start at the minimum stops
            after one or two iterations.
        progress : callable, optional
            Called with a :class:`SolveProgress` after every iteration (for
            a progress display of long solves; it should return quickly).
        **changes
            Option changes applied first (see :meth:`update`). If the solve
            is then refused (an ``OptionsError``: the targets, or a coarse
            model too large), the changes that needed no new set-up are
            taken back with it.

        Returns
        -------
        JoinResult
        """
        _check_progress(progress)
        before, made = self.options, self.factorizations
        if changes:
            self.update(**changes)
        try:
            return self._solve(targets, progress, start)
        except OptionsError:
            if changes and self.factorizations == made:
                # refused (e.g. the targets, or a model too large): changes that needed no new
                # set-up go back with it, so the next solve is the one before them
                self.options = before
            raise

    def _solve(self, targets: Any, progress: Any, start: Any) -> JoinResult:
        """:meth:`solve` once its option changes are applied."""
        c = self.corr
        opt = self.options
        bc = c.targets if targets is None else np.asarray(targets, dtype=np.float64)
        if bc.shape != c.targets.shape or not np.isfinite(bc).all():
            raise OptionsError(
                f"targets must be a finite array of shape {c.targets.shape} (one point per "
                "seam vertex)"
            )
        t0 = time.perf_counter()
        kept = hint = None
        if start is None:
            X0 = self.initial_guess(bc)
        else:
            start = self._start_positions(start)
            kept = self._kept_at(start)
            X0 = self._warm_start(start, bc, kept)
            if kept is not None and kept.rotations is not None:
                # the rotations the path's last run ended with, turned as its seam turns
                # onto the new targets
                hint = np.matmul(rigid_fit(start[c.seam], bc)[0], kept.rotations)
        t1 = time.perf_counter()

        def report(iteration: int, energy: float) -> None:
            elapsed = time.perf_counter() - t1
            progress(SolveProgress(iteration, opt.max_iterations, float(energy), elapsed))

        # the coarse model of the solve before, kept while its set-up and choice stand
        model = preferred_model(self.solver, opt, self._model)
        try:
            run = self.solver.run(
                X0,
                bc,
                max_iterations=opt.max_iterations,
                tolerance=opt.energy_tolerance,
                time_limit=opt.time_limit,
                scale=self.guest_mean_edge,
                acceleration=opt.acceleration,
                callback=None if progress is None else report,
                model=model,
                memory=None if kept is None else kept.memory,
                rotations=hint,
            )
        except BaseException:
            # a model refused or stopped mid-build is not one to continue from (one kept
            # before, not this solve's, stays)
            if self._model is model:
                self._model = None
            raise
        # P alone (None) lets the kept model go: its coarse factorization is large
        self._model = model
        t2 = time.perf_counter()
        if run.memory is not None and run.memory.S.nbytes + run.memory.Y.nbytes > PAIRS_MAX_BYTES:
            run.memory = None  # neither kept nor held by last_run past the run
        self.last_run, self.last_model = run, model
        result = join_result(
            run,
            bc,
            options=opt,
            host=self.host,
            host_offsets=self.host_offsets,
            host_values=self.host_values,
            pairs=self.pairs,
            parts=self.parts,
            corr=c,
            E=self.E,
            bands=self.bands,
            built=self.built,
            rest=self._rest,
        )
        if model is not None:
            result.coarse_model = {
                "in_use": model.fallback is None and model.coarse_factor is not None,
                "builds": int(run.stats["model_builds"]),
                "fallback": model.fallback,
            }
        self._keep(kept, run, result.guest.V)
        t3 = time.perf_counter()
        timings = dict(self.timings)
        timings.update(
            initial_guess=t1 - t0,
            local=run.timings["local"],
            back_solve=run.timings["solve"],
            iterate=t2 - t1,
            metrics=t3 - t2,
        )
        timings["total"] = sum(
            timings[k]
            for k in (
                "select",
                "correspond",
                "terms",
                "factor",
                "initial_guess",
                "iterate",
                "metrics",
            )
        )
        result.timings = timings
        result.metrics["time_seconds"] = timings["total"]
        return result


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (
            isinstance(a, np.ndarray)
            and isinstance(b, np.ndarray)
            and a.shape == b.shape
            and bool(np.array_equal(a, b))
        )
    return a == b


def join(
    host: Any,
    guest: Any,
    host_curve: Any = None,
    guest_curve: Any = None,
    *,
    seams: Any = None,
    smooth: bool = True,
    stiffness_regions: Any = None,
    progress: Any = None,
    **options: Any,
) -> JoinResult:
    """Deform ``guest`` so that its curves join ``host``'s curves exactly and smoothly.

    Same as ``JoinSolver(host, guest, host_curve, guest_curve, seams=seams,
    smooth=smooth, stiffness_regions=stiffness_regions,
    **options).solve(progress=progress)``.

    Parameters
    ----------
    host : Mesh or (V, F), or list of them
        One host mesh, or several joined as one (see :class:`JoinSolver`).
    guest : Mesh or (V, F)
    host_curve, guest_curve : curve specification, optional
        The curves of a single seam; see :class:`igljoin.Curve`.
    seams : list of tuple, optional
        Several seams in one solve: ``(host_curve, guest_curve)`` or
        ``(host_index, host_curve, guest_curve)`` each (instead of
        ``host_curve``/``guest_curve``).
    smooth : bool
        Include the smooth-join terms.
    stiffness_regions : list of (vertex_indices, k), optional
        Relative stiffness of regions of guest vertices (1 elsewhere).
    progress : callable, optional
        Called with a :class:`SolveProgress` after every iteration.
    **options
        See :class:`igljoin.JoinOptions`; ``stiffness`` may be an array
        (per guest vertex or face) or the name of a guest attribute.

    Returns
    -------
    JoinResult

    Examples
    --------
    >>> import igljoin
    >>> g = igljoin.phantoms.bypass_graft_sample()
    >>> res = igljoin.join(g.hosts, g.guest, seams=g.seams)
    >>> res.converged, len(res.seams)
    (True, 2)
    """
    _check_progress(progress)  # before the setup, which can take long on big meshes
    return JoinSolver(
        host,
        guest,
        host_curve,
        guest_curve,
        seams=seams,
        smooth=smooth,
        stiffness_regions=stiffness_regions,
        **options,
    ).solve(progress=progress)
