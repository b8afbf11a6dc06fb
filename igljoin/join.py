"""Join a flexible guest to a rigid host: ``JoinSolver`` and ``join()``.

The steps follow the paper: select the boundary curves (§3), map them onto
each other and insert host points into the guest (§4.1), build the shape,
stretch and smooth-join terms (§4.2–4.4) and minimise them under the hard
seam constraints by a local/global iteration (§4.5).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from . import metrics
from .boundary import Curve, boundary_loops, select_curve
from .correspond import correspond, pair_curves
from .errors import OptionsError
from .frames import SeamFrames, face_normals_areas, seam_frames, unit
from .mesh import Mesh, as_mesh
from .options import JoinOptions
from .result import JoinResult
from .solve import LocalGlobalSolver
from .terms import ShapeTerm, SmoothJoinTerm, StretchTerm, edge_stiffness, unique_edges
from .validate import check_guest_reaches_seam, check_surface

__all__ = ["JoinSolver", "JoinResult", "join"]

# options that change the quadratic form (and so need a new factorization)
_STRUCTURAL = {
    "smooth",
    "shape_weight",
    "stretch_weight",
    "smooth_weight",
    "smooth_mode",
    "smooth_radius",
    "smooth_tolerance",
    "laplacian",
    "rotation_aware",
    "stiffness",
    "stiffness_on",
    "snap_tolerance",
    "linear_solver",
}


def _rigid_fit(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R (3, 3) and translation t (3,) minimising ‖A Rᵀ + t − B‖ (proper rotation)."""
    ca, cb = A.mean(axis=0), B.mean(axis=0)
    H = (A - ca).T @ (B - cb)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0])
    R = Vt.T @ D @ U.T
    return R, cb - ca @ R.T


def _interpolate_frames(frames: SeamFrames, edge: np.ndarray, t: np.ndarray, closed: bool):
    k = len(frames.normal)
    nxt = (edge + 1) % k if closed else np.minimum(edge + 1, k - 1)

    def lerp(A):
        return unit(A[edge] * (1.0 - t)[:, None] + A[nxt] * t[:, None])

    normal = lerp(frames.normal)
    inward = lerp(frames.inward)
    inward = unit(inward - np.einsum("ij,ij->i", inward, normal)[:, None] * normal)
    return SeamFrames(normal=normal, tangent=lerp(frames.tangent), inward=inward)


class JoinSolver:
    """Prepare a join once; solve it, and re-solve cheaply.

    Parameters
    ----------
    host : Mesh or (V, F)
        The rigid host.
    guest : Mesh or (V, F)
        The flexible guest.
    host_curve, guest_curve : None, Curve, mapping, int or array_like of int
        The boundary curves to join (see :class:`igljoin.Curve`). ``None``
        takes the only boundary loop; for a closed guest curve without a
        start, the start is found by fitting the curves rigidly.
    options : JoinOptions or dict, optional
    **overrides
        Individual options (see :class:`igljoin.JoinOptions`).

    Notes
    -----
    The factorization of the quadratic form is kept: :meth:`solve` with new
    seam targets or iteration settings reuses it; changing a weight or the
    smooth term rebuilds it (:attr:`factorizations` counts them).

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
        **overrides: Any,
    ):
        t0 = time.perf_counter()
        self.options = JoinOptions.make(options, **overrides)
        self.host = as_mesh(host, "host")
        self.guest = as_mesh(guest, "guest")
        if self.host.name == "mesh":
            self.host = Mesh(self.host.V, self.host.F, name="host")
        if self.guest.name == "mesh":
            self.guest = Mesh(self.guest.V, self.guest.F, name="guest")
        check_surface(self.host, "host")
        check_surface(self.guest, "guest")
        hc = select_curve(self.host, host_curve, name="host_curve")
        gspec = Curve.coerce(guest_curve, "guest_curve")
        gc = select_curve(self.guest, gspec, name="guest_curve")
        start_given = gspec.start is not None or gspec.indices is not None
        self.host_curve, self.guest_curve, self.pairing = pair_curves(
            self.host.V, hc, self.guest.V, gc, guest_start_given=start_given
        )
        self.factorizations = 0
        self.last_run = None  # IterationResult of the latest solve (iteration statistics)
        self.timings: dict[str, float] = {"select": time.perf_counter() - t0}
        self._prepare()

    # -- set-up -----------------------------------------------------------------------------

    def _prepare(self) -> None:
        t0 = time.perf_counter()
        opt = self.options
        self.corr = correspond(
            self.guest.V,
            self.guest.F,
            self.guest_curve,
            self.host.V,
            self.host_curve,
            snap_tolerance=opt.snap_tolerance,
        )
        c = self.corr
        check_guest_reaches_seam(c.F, len(c.V), c.seam)
        t1 = time.perf_counter()
        hv = self.host.V[self.host_curve.indices]
        seg = np.roll(hv, -1, axis=0) - hv if self.host_curve.closed else np.diff(hv, axis=0)
        self.host_mean_edge = float(np.linalg.norm(seg, axis=1).mean())
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
        if opt.smooth and opt.smooth_weight > 0:
            radius = None if opt.smooth_mode == "paper" else opt.smooth_radius * self.host_mean_edge
            radius = radius or None
            frames = seam_frames(
                self.host.V,
                self.host.F,
                self.host_curve.indices,
                self.host_curve.closed,
                radius=radius,
            )
            at_seam = _interpolate_frames(
                frames, c.host_edge, c.host_edge_t, self.host_curve.closed
            )
            self.smooth_tolerance_deg = self._smooth_tolerance(frames)
            terms.append(
                SmoothJoinTerm(
                    c.V,
                    c.F,
                    c.seam,
                    at_seam,
                    opt.smooth_weight,
                    opt.smooth_mode,
                    np.radians(self.smooth_tolerance_deg),
                )
            )
        self.terms = terms
        t2 = time.perf_counter()
        self.solver = LocalGlobalSolver(terms, len(c.V), c.seam, opt.linear_solver)
        self.factorizations += 1
        self.timings.update(correspond=t1 - t0, terms=t2 - t1, factor=self.solver.factor_seconds)

    def _smooth_tolerance(self, smoothed: SeamFrames) -> float:
        """Crease (degrees) the robust smooth join tolerates: the host's own normal noise.

        The median angle between the host's one-ring and smoothed cross-seam
        directions along the curve, unless ``smooth_tolerance`` is given.
        """
        opt = self.options
        if opt.smooth_mode == "paper" or (opt.smooth_tolerance is None and opt.smooth_radius == 0):
            return 0.0
        if opt.smooth_tolerance is not None:
            return float(opt.smooth_tolerance)
        onering = seam_frames(
            self.host.V, self.host.F, self.host_curve.indices, self.host_curve.closed
        )
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

    def update(self, **changes: Any) -> None:
        """Change options; the factorization is rebuilt only if the quadratic form changes."""
        new = self.options.replace(**changes)
        old = self.options
        self.options = new
        structural = any(not _same(getattr(old, name), getattr(new, name)) for name in _STRUCTURAL)
        if structural:
            self._prepare()

    def initial_guess(self, targets: np.ndarray | None = None) -> np.ndarray:
        """Rigidly aligned rest guest, with the seam displacement smoothly extended.

        Returns shape (n', 3).
        """
        c = self.corr
        bc = c.targets if targets is None else targets
        R, t = _rigid_fit(c.V[c.seam], bc)
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
        if not self.host_curve.closed or len(boundary_loops(c.F)) != 1:
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

    def solve(self, targets: np.ndarray | None = None, **changes: Any) -> JoinResult:
        """Deform the guest.

        Parameters
        ----------
        targets : ndarray, shape (s, 3), optional
            New positions for the seam vertices (default: the host curve
            correspondence). Reuses the factorization.
        **changes
            Option changes applied first (see :meth:`update`).

        Returns
        -------
        JoinResult
        """
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
        X0 = self.initial_guess(bc)
        t1 = time.perf_counter()
        run = self.solver.run(
            X0,
            bc,
            max_iterations=opt.max_iterations,
            tolerance=opt.tolerance,
            time_limit=opt.time_limit,
            scale=self.guest_mean_edge,
            acceleration=opt.acceleration,
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
        hc = self.host_curve
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
        guest_at_host = c.seam[c.host_hit]
        crease = metrics.crease_angles(
            self.host.V, self.host.F, hc.indices, X, c.F, guest_at_host, hc.closed
        )
        host_dihedral = metrics.host_dihedral_angles(self.host.V, self.host.F, hc.indices)
        rows = sum(t.soft_rows for t in self.terms)
        counts = {
            "points": len(c.V),
            "hard": 3 * len(c.seam),
            "soft": 3 * rows,
            "seam": len(c.seam),
            "inserted": len(c.inserted_t),
            "faces": len(c.F),
            "host_curve": len(hc.indices),
        }
        folds = metrics.folded_pairs(c.V, X, c.F)
        total_ratio = float(
            face_normals_areas(X, c.F)[1].sum() / face_normals_areas(c.V, c.F)[1].sum()
        )
        m = {
            "seam_gap": metrics.seam_gap(X[c.seam], self.host.V[hc.indices], hc.closed),
            "crease_deg": {**metrics.summary(crease)},
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
        }
        result = JoinResult(
            host=self.host,
            guest=guest,
            rest_guest=rest,
            seam=c.seam.copy(),
            host_curve=hc.indices.copy(),
            seam_targets=np.array(bc),
            closed=hc.closed,
            area_ratio=ratio,
            converged=run.converged,
            iterations=run.iterations,
            energy=list(run.energy),
            counts=counts,
            timings={},
            options=self.options,
            correspondence=c,
            crease=crease,
            metrics=m,
            stop_reason=run.reason,
            pairing=self.pairing,
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
    smooth: bool = True,
    **options: Any,
) -> JoinResult:
    """Deform ``guest`` so that its curve joins ``host``'s curve exactly and smoothly.

    Same as ``JoinSolver(host, guest, host_curve, guest_curve, smooth=smooth, **options).solve()``.

    Parameters
    ----------
    host, guest : Mesh or (V, F)
    host_curve, guest_curve : curve specification, optional
        See :class:`igljoin.Curve`.
    smooth : bool
        Include the smooth-join term.
    **options
        See :class:`igljoin.JoinOptions`.

    Returns
    -------
    JoinResult
    """
    return JoinSolver(host, guest, host_curve, guest_curve, smooth=smooth, **options).solve()
