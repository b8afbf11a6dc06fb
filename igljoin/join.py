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
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import band_targets, crease, metrics
from . import seams as seams_
from .bandfit import band_fit
from .boundary import SelectedCurve, boundary_loops
from .correspond import rigid_fit
from .errors import OptionsError
from .frames import SeamFrames, face_normals_areas, seam_frames, unit
from .measure import combined_gap
from .mesh import Mesh, as_mesh
from .options import JoinOptions
from .polyline import mean_segment
from .result import JoinedSeam, JoinResult
from .seams import SeamPair
from .solve import LocalGlobalSolver
from .stiffness import stiffness_from_attribute, stiffness_from_regions
from .terms import (
    ShapeTerm,
    SmoothJoinTerm,
    StretchTerm,
    edge_stiffness,
    unique_edges,
)
from .validate import check_surface

__all__ = ["JoinSolver", "JoinResult", "SeamPair", "SolveProgress", "join"]

# options that change the quadratic form (and so need a new factorization)
_STRUCTURAL = JoinOptions.structural_fields()

#: A host with more faces than this is checked near its curves only
#: (:func:`igljoin.seams.host_neighbourhood`).
HOST_CHECK_ALL_FACES = 200_000



def _interpolate_frames(frames: SeamFrames, edge: np.ndarray, t: np.ndarray, closed: bool):
    k = len(frames.normal)
    nxt = (edge + 1) % k if closed else np.minimum(edge + 1, k - 1)

    def lerp(A):
        return unit(A[edge] * (1.0 - t)[:, None] + A[nxt] * t[:, None])

    normal = lerp(frames.normal)
    inward = lerp(frames.inward)
    inward = unit(inward - np.einsum("ij,ij->i", inward, normal)[:, None] * normal)
    return SeamFrames(normal=normal, tangent=lerp(frames.tangent), inward=inward)


def _guest_mesh(guest: Any) -> Mesh:
    """The guest as a :class:`Mesh` named "guest" (attributes kept)."""
    mesh = as_mesh(guest, "guest")
    if mesh.name == "mesh":
        mesh = Mesh(mesh.V, mesh.F, mesh.vertex_attributes, mesh.face_attributes, name="guest")
    return mesh


def _given(options: Any, overrides: dict, name: str) -> Any:
    """The value of option ``name`` in ``overrides``, else in ``options``, else ``None``."""
    if name in overrides:
        return overrides[name]
    if isinstance(options, JoinOptions):
        return getattr(options, name)
    if isinstance(options, Mapping):
        return options.get(name)
    return None


def _needs_guest(options: Any, overrides: dict, regions: Any) -> bool:
    """Whether the stiffness must be resolved against the guest (regions or a name)."""
    return regions is not None or isinstance(_given(options, overrides, "stiffness"), str)


def _resolve_stiffness(guest: Mesh, options: Any, overrides: dict, regions: Any) -> dict:
    """``overrides`` with ``stiffness`` given as regions or as an attribute name made an array.

    Parameters
    ----------
    guest : Mesh
    options : JoinOptions, dict or None
    overrides : dict
        Keyword options; ``overrides["stiffness"]`` (or ``options``') may be a
        guest attribute name.
    regions : list of (vertex_indices, k) or None

    Returns
    -------
    dict
        ``overrides`` with ``stiffness`` (ndarray) and ``stiffness_on`` set.
    """
    given = _given(options, overrides, "stiffness")
    if regions is not None:
        if given is not None:
            raise OptionsError(
                "give either stiffness or stiffness_regions, not both; for regions on top of a "
                "map, pass stiffness=stiffness_from_regions(n, regions, default=...) yourself"
            )
        values, on = stiffness_from_regions(guest.n_vertices, regions), "vertex"
    else:
        values, on = stiffness_from_attribute(guest, given)
    on_given = _given(options, overrides, "stiffness_on")
    if on_given not in (None, "auto", on):
        raise OptionsError(
            f"stiffness_on={on_given!r} but the stiffness map is per {on}; leave stiffness_on "
            "unset (it is set from where the map was found)"
        )
    return {**overrides, "stiffness": values, "stiffness_on": on}


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

    Notes
    -----
    The factorization of the quadratic form is kept: :meth:`solve` with new
    seam targets or iteration settings reuses it; changing a weight or the
    smooth term rebuilds it (:attr:`factorizations` counts them).
    ``solve(targets, start=previous_result)`` also starts from the previous
    result, which after a small change of the targets needs fewer
    iterations.

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
        if _needs_guest(options, overrides, stiffness_regions):
            guest_mesh = _guest_mesh(guest)
            overrides = _resolve_stiffness(guest_mesh, options, overrides, stiffness_regions)
        self.options = JoinOptions.make(options, **overrides)
        # §3: the hosts, and the curves of every seam selected and paired
        self.hosts, self.host, self.host_offsets, several = seams_.load_hosts(host)
        self.guest = _guest_mesh(guest) if guest_mesh is None else guest_mesh
        self._host_near = None if several else seams_.host_neighbourhood(
            self.host, host_curve, seams, HOST_CHECK_ALL_FACES
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
        self.factorizations = 0
        self.last_run = None  # IterationResult of the latest solve (iteration statistics)
        self.timings: dict[str, float] = {"select": time.perf_counter() - t0}
        self._prepare()

    # -- set-up -----------------------------------------------------------------------------

    def _prepare(self) -> None:
        t0 = time.perf_counter()
        opt = self.options
        # §4.1: the curves mapped onto each other, host points inserted into the guest
        parts, c = seams_.correspond_seams(
            self.guest.V, self.guest.F, self.host.V, self.pairs, opt.snap_fraction
        )
        self.parts, self.corr = parts, c
        t1 = time.perf_counter()
        self.host_mean_edges = []
        for p in self.pairs:
            hv = self.host.V[p.host_curve.indices]
            self.host_mean_edges.append(mean_segment(hv, p.host_curve.closed))
        self.host_mean_edge = float(np.mean(self.host_mean_edges))
        self.E = unique_edges(c.F)
        self.guest_mean_edge = float(
            np.linalg.norm(c.V[self.E[:, 0]] - c.V[self.E[:, 1]], axis=1).mean()
        )
        terms = []
        if opt.shape_weight > 0:
            terms.append(
                ShapeTerm(c.V, c.F, opt.shape_weight, opt.laplacian, opt.rotation_aware, E=self.E)
            )
        if opt.stretch_weight > 0:
            k = edge_stiffness(self.E, c.F, *self._stiffness())
            terms.append(StretchTerm(c.V, self.E, opt.stretch_weight * k))
        self.smooth_keep_degs = []
        self.crease_removed = []
        self._rest_fits = {}  # the rest guest's band fits along its seams (see _result)
        self.bands = [
            opt.smooth_band
            or crease.default_band(
                self.host.V, self.host.F, p.host_curve.indices, c.V, c.F, part.seam
            )
            for p, part in zip(self.pairs, parts)
        ]
        if opt.smooth and opt.smooth_weight > 0 and opt.smooth_mode == "band":
            angles = self._join_angles()
            for p, part, band, angle in zip(self.pairs, parts, self.bands, angles):
                terms.append(self._band_term(p.host_curve, part, band, angle))
        elif opt.smooth and opt.smooth_weight > 0:
            for p, part, mean_edge in zip(self.pairs, parts, self.host_mean_edges):
                hc = p.host_curve
                radius = None if opt.smooth_mode == "paper" else opt.smooth_radius * mean_edge
                radius = radius or None
                frames = seam_frames(self.host.V, self.host.F, hc.indices, hc.closed, radius=radius)
                at_seam = _interpolate_frames(frames, part.host_edge, part.host_edge_t, hc.closed)
                tolerance = self._smooth_keep_deg(frames, hc)
                self.smooth_keep_degs.append(tolerance)
                terms.append(
                    SmoothJoinTerm(
                        c.V,
                        c.F,
                        part.seam,
                        at_seam,
                        opt.smooth_weight,
                        opt.smooth_mode,
                        np.radians(tolerance),
                    )
                )
        self.smooth_keep_deg = max(self.smooth_keep_degs, default=0.0)
        self.terms = terms
        t2 = time.perf_counter()
        self.solver = LocalGlobalSolver(terms, len(c.V), c.seam, opt.linear_solver)
        self.factorizations += 1
        self.timings.update(correspond=t1 - t0, terms=t2 - t1, factor=self.solver.factor_seconds)

    def _join_angles(self) -> list:
        """``join_angle`` per seam (None: the default smooth join)."""
        angle, k = self.options.join_angle, len(self.pairs)
        if not isinstance(angle, tuple):
            return [angle] * k
        if len(angle) != k:
            raise OptionsError(
                f"join_angle has {len(angle)} values for {k} seam{'s' if k != 1 else ''}; "
                "give one per seam (None keeps a seam's default) or a single angle"
            )
        return list(angle)

    def _host_cached(self, key: tuple, make):
        """A value of the rigid host, made once per solver (``make()`` the first time)."""
        cache = self.__dict__.setdefault("_host_values", {})
        if key not in cache:
            cache[key] = make()
        return cache[key]

    def _host_fit(self, hc: SelectedCurve, band: float):
        """The host's band fit along a curve."""
        key = ("band_fit", hc.indices.tobytes(), bool(hc.closed), float(band))
        return self._host_cached(
            key, lambda: band_fit(self.host.V, self.host.F, hc.indices, hc.closed, band)
        )

    def _host_inward(self, hc: SelectedCurve) -> np.ndarray:
        """The host's one-ring inward directions along a curve (the one-ring crease's)."""
        host = self.host if self._host_near is None else self._host_near
        key = ("inward", hc.indices.tobytes(), bool(hc.closed))
        return self._host_cached(
            key, lambda: seam_frames(host.V, host.F, hc.indices, hc.closed).inward
        )

    def _host_dihedral(self, curve: np.ndarray) -> np.ndarray:
        """The host's own dihedral angles near a curve (``metrics.host_dihedral_angles``)."""
        host = self.host if self._host_near is None else self._host_near
        key = ("dihedral", np.asarray(curve).tobytes())
        return self._host_cached(
            key, lambda: metrics.host_dihedral_angles(host.V, host.F, curve)
        )

    def _band_term(
        self, hc: SelectedCurve, part, band: float, angle: float | None = None
    ) -> SmoothJoinTerm:
        """The band smooth-join term of one seam (:mod:`igljoin.band_targets`).

        The host's band-fitted tangent planes at the seam targets are tilted by
        the elevation the join keeps (the rest guest's, less the crease coherent
        along the seam), and the guest's band-fitted direction off each seam
        vertex is pulled into them. ``smooth_keep_deg`` widens that into a wedge.
        """
        c, opt = self.corr, self.options
        host_fit = self._host_fit(hc, band)
        at_seam = _interpolate_frames(host_fit.frames, part.host_edge, part.host_edge_t, hc.closed)
        guest_fit = band_fit(c.V, c.F, part.seam, hc.closed, band)
        k = len(hc.indices)
        edge, t = part.host_edge, part.host_edge_t
        nxt = (edge + 1) % k if hc.closed else np.minimum(edge + 1, k - 1)
        P = self.host.V[hc.indices]
        targets = P[edge] * (1.0 - t)[:, None] + P[nxt] * t[:, None]
        host_se = host_fit.slope_error[edge] * (1.0 - t) + host_fit.slope_error[nxt] * t
        kept, removed = band_targets.kept_elevation(
            at_seam,
            guest_fit.frames.inward,
            c.V[part.seam],
            targets,
            np.hypot(host_se, guest_fit.slope_error),
            hc.closed,
            band,
            join_angle=angle,
            join_side=opt.join_side,
        )
        self.crease_removed.append(np.degrees(np.abs(removed)))
        tolerance = float(opt.smooth_keep_deg or 0.0)
        self.smooth_keep_degs.append(tolerance)
        return SmoothJoinTerm(
            c.V,
            c.F,
            part.seam,
            band_targets.tilted_frames(at_seam, kept),
            opt.smooth_weight,
            "band",
            np.radians(tolerance),
            fit=guest_fit,
        )

    def _smooth_keep_deg(self, smoothed: SeamFrames, hc: SelectedCurve) -> float:
        """Crease (degrees) the robust smooth join tolerates: the host's own normal noise.

        The median angle between the host's one-ring and smoothed cross-seam
        directions along the curve ``hc``, unless ``smooth_keep_deg`` is given.
        """
        opt = self.options
        if opt.smooth_mode == "paper" or (opt.smooth_keep_deg is None and opt.smooth_radius == 0):
            return 0.0
        if opt.smooth_keep_deg is not None:
            return float(opt.smooth_keep_deg)
        onering = seam_frames(self.host.V, self.host.F, hc.indices, hc.closed)
        cos = np.clip(np.einsum("ij,ij->i", onering.inward, smoothed.inward), -1.0, 1.0)
        return float(np.degrees(np.median(np.arccos(cos))))

    def _stiffness(self) -> tuple[np.ndarray | None, str]:
        opt = self.options
        if opt.stiffness is None:
            return None, "vertex"
        k = opt.stiffness
        n, m = self.guest.n_vertices, self.guest.n_faces
        on = opt.stiffness_on
        if on == "auto":
            if len(k) == n == m:
                raise OptionsError(
                    "stiffness: the guest has as many vertices as faces, so a stiffness array "
                    "is ambiguous; set stiffness_on='vertex' or 'face'"
                )
            on = "vertex" if len(k) == n else "face" if len(k) == m else "?"
        expected = n if on == "vertex" else m
        if on == "?" or len(k) != expected:
            raise OptionsError(
                f"stiffness has {len(k)} values; give one per guest vertex ({n}) or per guest "
                f"face ({m})"
            )
        c = self.corr
        if on == "vertex":
            a, b = c.inserted_from[:, 0], c.inserted_from[:, 1]
            extra = k[a] * (1.0 - c.inserted_t) + k[b] * c.inserted_t
            return np.concatenate([k, extra]), "vertex"
        return k[c.face_parent], "face"

    # -- solving ----------------------------------------------------------------------------

    def update(self, *, stiffness_regions: Any = None, **changes: Any) -> None:
        """Change options; the factorization is rebuilt only if the quadratic form changes.

        ``stiffness`` may name a guest attribute, and ``stiffness_regions``
        replaces the stiffness map, as in the constructor.
        """
        if _needs_guest(None, changes, stiffness_regions):
            changes = _resolve_stiffness(self.guest, None, changes, stiffness_regions)
        new = self.options.replace(**changes)
        old = self.options
        self.options = new
        structural = any(not _same(getattr(old, name), getattr(new, name)) for name in _STRUCTURAL)
        if structural:
            self._prepare()

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
        R, t = rigid_fit(c.V[c.seam], bc)
        X = c.V @ R.T + t
        if self.options.initial_guess == "extend":
            X = X + self.solver.extend(bc - X[c.seam])
            X = self._bulge(X)
        return X

    def _bulge(self, X: np.ndarray) -> np.ndarray:
        """Lift a compressed disk-like guest off its plane so that it bulges instead of shrinking.

        A guest whose boundary is longer than the host's (paper §5: "it bulged
        to match the shape of the host") would otherwise start from a flat,
        compressed state that the iteration leaves only slowly. The lift is
        the guest's response to a unit load along the host's mean seam normal,
        on the side the host surface curves towards, with its height chosen
        so that the guest's area is its rest area.
        """
        c = self.corr
        if len(self.pairs) != 1 or not self.host_curve.closed or len(boundary_loops(c.F)) != 1:
            return X
        rest = face_normals_areas(c.V, c.F)[1].sum()
        if face_normals_areas(X, c.F)[1].sum() >= (1.0 - 1e-3) * rest:
            return X
        frames = seam_frames(self.host.V, self.host.F, self.host_curve.indices, True)
        N = frames.normal.mean(axis=0)
        if np.linalg.norm(N) == 0:
            return X
        N = N / np.linalg.norm(N)
        side = float(np.mean(-frames.inward @ N))
        if abs(side) < 1e-3:
            side = float((c.V.mean(axis=0) - c.V[c.seam].mean(axis=0)) @ N) or 1.0
        phi = self.solver.bump()
        if phi.max() <= 0:
            return X
        lift = np.sign(side) * (phi / phi.max())[:, None] * N

        def area(a):
            return face_normals_areas(X + a * lift, c.F)[1].sum()

        hi = float(np.linalg.norm(np.ptp(c.V, axis=0)))
        if area(hi) < rest:
            return X + hi * lift
        lo = 0.0
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if area(mid) < rest else (lo, mid)
        return X + 0.5 * (lo + hi) * lift

    def warm_start(self, start: Any, targets: np.ndarray) -> np.ndarray:
        """Positions ``start`` with their seam moved onto ``targets``, the move extended smoothly.

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
        return X + self.solver.extend(targets - X[self.corr.seam])

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
            moved onto the targets and the move extended smoothly
            (:meth:`warm_start`). A start at the minimum stops after one or
            two iterations.
        progress : callable, optional
            Called with a :class:`SolveProgress` after every iteration (for
            a progress display of long solves; it should return quickly).
        **changes
            Option changes applied first (see :meth:`update`).

        Returns
        -------
        JoinResult
        """
        _check_progress(progress)
        if changes:
            self.update(**changes)
        c = self.corr
        opt = self.options
        bc = c.targets if targets is None else np.asarray(targets, dtype=np.float64)
        if bc.shape != c.targets.shape or not np.isfinite(bc).all():
            raise OptionsError(
                f"targets must be a finite array of shape {c.targets.shape} (one point per "
                "seam vertex)"
            )
        t0 = time.perf_counter()
        X0 = self.initial_guess(bc) if start is None else self.warm_start(start, bc)
        t1 = time.perf_counter()

        def report(iteration: int, energy: float) -> None:
            elapsed = time.perf_counter() - t1
            progress(SolveProgress(iteration, opt.max_iterations, float(energy), elapsed))

        run = self.solver.run(
            X0,
            bc,
            max_iterations=opt.max_iterations,
            tolerance=opt.energy_tolerance,
            time_limit=opt.time_limit,
            scale=self.guest_mean_edge,
            acceleration=opt.acceleration,
            callback=None if progress is None else report,
        )
        t2 = time.perf_counter()
        self.last_run = run
        result = self._result(run, bc)
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

    def _result(self, run, bc) -> JoinResult:
        c = self.corr
        X = run.X
        host = self.host if self._host_near is None else self._host_near  # same vertex ids
        ratio = metrics.area_ratio(c.V, X, c.F)
        strain = metrics.edge_strain(c.V, X, self.E)
        vertex_strain = metrics.vertex_strain(self.E, strain, len(X))
        displacement = metrics.nonrigid_displacement(c.V, X)
        on_seam = np.zeros(len(X), dtype=bool)
        on_seam[c.seam] = True
        guest = Mesh(
            X,
            c.F,
            vertex_attributes={
                "displacement": displacement,
                "strain": vertex_strain,
                "seam": on_seam,
            },
            face_attributes={"area_ratio": ratio},
            name="deformed guest",
        )
        rest = Mesh(c.V, c.F, name="rest guest")
        seams, per_seam, gaps = [], [], []
        start = 0
        onering_all, measured_all, inputs_all, off_angle_all = [], [], [], []
        asked = self._join_angles() if self.options.smooth_mode == "band" else []
        asked = asked if self.options.smooth else []
        for i, (p, part, band) in enumerate(zip(self.pairs, self.parts, self.bands)):
            hc = p.host_curve
            s = len(part.seam)
            at_host = part.seam[part.host_hit]
            host_fit = self._host_fit(hc, band)
            # the rest guest is fixed too (until the next _prepare): its fit along the
            # seam serves both measures, on every solve
            key = (at_host.tobytes(), bool(hc.closed), float(band))
            if key not in self._rest_fits:
                self._rest_fits[key] = band_fit(c.V, c.F, at_host, hc.closed, band)
            rest_fit = self._rest_fits[key]
            measured = crease.seam_crease(
                host.V, host.F, hc.indices, X, c.F, at_host, hc.closed, band, c.V, host_fit,
                rest_fit,
            )  # fmt: skip
            inputs = crease.input_crease(
                host.V, host.F, hc.indices, c.V, c.F, at_host, hc.closed, band, host_fit,
                rest_fit,
            )  # fmt: skip
            onering = metrics.crease_angles(
                host.V, host.F, hc.indices, X, c.F, at_host, hc.closed, self._host_inward(hc)
            )
            measured_all.append(measured)
            inputs_all.append(inputs)
            onering_all.append(onering)
            angle = asked[i] if asked else None
            if any(asked):
                # how far the guest leaves the host from the angle asked for (0 where
                # a seam keeps the smooth join)
                off = np.abs(measured.angles - (angle or 0.0))
                off_angle_all.append(crease.CreaseMeasure(off, band, measured.noise))
            gap = metrics.seam_gap(X[part.seam], host.V[hc.indices], hc.closed)
            gaps.append(gap)
            dihedral = self._host_dihedral(hc.indices)
            seams.append(
                JoinedSeam(
                    host_index=p.host_index,
                    host_curve=hc.indices.copy(),
                    seam=part.seam.copy(),
                    closed=hc.closed,
                    targets=np.array(bc[start : start + s]),
                    host_hit=part.host_hit.copy(),
                    host_edge=part.host_edge.copy(),
                    host_edge_t=part.host_edge_t.copy(),
                    inserted=len(part.inserted_t),
                    crease=measured.angles,
                    pairing=dict(p.pairing),
                )
            )
            per_seam.append(
                {
                    "host_index": p.host_index,
                    "closed": hc.closed,
                    "seam": s,
                    "host_curve": len(hc.indices),
                    "inserted": len(part.inserted_t),
                    "seam_gap": gap,
                    "crease_deg": crease.report([measured]),
                    "crease_onering_deg": metrics.summary(onering),
                    "input_crease_deg": crease.report([inputs]),
                    "join_angle_deg": angle,
                    "join_angle_error_deg": (
                        crease.report([off_angle_all[-1]]) if off_angle_all else None
                    ),
                    "crease_removed_deg": metrics.summary(
                        self.crease_removed[len(per_seam)]
                        if self.crease_removed
                        else np.zeros(0)
                    ),
                    "host_dihedral_deg": {
                        **metrics.summary(dihedral),
                        "rings": metrics.HOST_DIHEDRAL_RINGS,
                    },
                }
            )
            start += s
        host_curve = np.concatenate([sm.host_curve for sm in seams])
        seam_creases = np.concatenate([sm.crease for sm in seams])
        host_dihedral = self._host_dihedral(host_curve)
        rows = sum(t.soft_rows for t in self.terms)
        counts = {
            "points": len(c.V),
            "hard": 3 * len(c.seam),
            "soft": 3 * rows,
            "seam": len(c.seam),
            "inserted": len(c.inserted_t),
            "faces": len(c.F),
            "host_curve": len(host_curve),
            "seams": len(seams),
        }
        folds = metrics.folded_pairs(c.V, X, c.F)
        total_ratio = float(
            face_normals_areas(X, c.F)[1].sum() / face_normals_areas(c.V, c.F)[1].sum()
        )
        m = {
            "seam_gap": combined_gap(gaps, [len(sm.seam) for sm in seams]),
            "crease_deg": crease.report(measured_all),
            "crease_onering_deg": metrics.summary(np.concatenate(onering_all)),
            "input_crease_deg": crease.report(inputs_all),
            "join_angle_error_deg": crease.report(off_angle_all) if off_angle_all else None,
            "host_dihedral_deg": {
                **metrics.summary(host_dihedral),
                "rings": metrics.HOST_DIHEDRAL_RINGS,
            },
            "area_ratio": {**metrics.summary(ratio), "total": total_ratio},
            "area_change": metrics.summary(np.abs(ratio - 1.0)),
            "strain": metrics.summary(strain),
            "vertex_strain": metrics.summary(vertex_strain),
            "displacement_nonrigid": metrics.summary(displacement),
            "folded_pairs": len(folds),
            "crease_removed_deg": metrics.summary(
                np.concatenate(self.crease_removed) if self.crease_removed else np.zeros(0)
            ),
            "seams": per_seam,
        }
        result = JoinResult(
            host=self.host,
            guest=guest,
            rest_guest=rest,
            seams=seams,
            seam_targets=np.array(bc),
            area_ratio=ratio,
            converged=run.converged,
            iterations=run.iterations,
            energy=list(run.energy),
            counts=counts,
            timings={},
            options=self.options,
            correspondence=c,
            crease=seam_creases,
            metrics=m,
            stop_reason=run.reason,
            host_offsets=self.host_offsets.copy(),
        )
        # weld (kept in the result) and count self-intersections near the seam
        result.metrics.update(result.measure_weld())
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
