"""The outcome of a join: deformed guest, correspondence, measurements, output files."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .atomic import atomic_write_text
from .correspond import Correspondence
from .errors import WeldError
from .io import DEFAULT_OUTPUT_FORMATS, output_formats, write_mesh
from .mesh import Mesh
from .metrics import SELF_INTERSECTION_RINGS, ring_band, self_intersections
from .options import JoinOptions
from .plain import plain_json
from .quality import QualityWarning, assess
from .weld import Welded, weld

__all__ = ["JoinResult", "JoinedSeam", "plain_json"]


def _with_quality(mesh: Mesh) -> Mesh:
    """``mesh`` with ``quality`` copies of its displacement (vertices) and area ratio (faces).

    MeshLab reads no other per-element property of a PLY file.
    """
    va, fa = mesh.vertex_attributes, mesh.face_attributes
    vertex = {"quality": va["displacement"]} if "displacement" in va else {}
    face = {"quality": fa["area_ratio"]} if "area_ratio" in fa else {}
    return mesh.with_attributes(vertex=vertex, face=face)


@dataclass(frozen=True, eq=False)
class JoinedSeam:
    """One seam of a join: a guest curve held on a host curve.

    Attributes
    ----------
    host_index : int
        Which host mesh the curve is on (0 for a single host mesh).
    host_curve : ndarray of int64, shape (k,)
        Host curve vertices in curve order, as indices into the combined
        host ``JoinResult.host``.
    seam : ndarray of int64, shape (s,)
        Guest seam vertices in curve order (indices into ``JoinResult.guest``).
    closed : bool
    targets : ndarray, shape (s, 3)
        Where each seam vertex was held.
    host_hit : ndarray of int64, shape (k,)
        For each host curve vertex, the position in ``seam`` of the guest
        vertex on it.
    host_edge : ndarray of int64, shape (s,)
        For each seam vertex, the segment of ``host_curve`` it lies on
        (segment ``j`` joins ``host_curve[j]`` and ``host_curve[j + 1]``,
        wrapping on a closed curve).
    host_edge_t : ndarray, shape (s,)
        Position within that segment, in ``[0, 1]``.
    inserted : int
        Guest vertices inserted on this seam.
    crease : ndarray, shape (k,)
        Crease angle (degrees) at each host curve vertex.
    pairing : dict
        Rigid-fit residuals of the start search (closed curves; see
        :func:`igljoin.correspond.pair_curves`).
    """

    host_index: int
    host_curve: np.ndarray
    seam: np.ndarray
    closed: bool
    targets: np.ndarray
    host_hit: np.ndarray
    host_edge: np.ndarray
    host_edge_t: np.ndarray
    inserted: int
    crease: np.ndarray
    pairing: dict = field(default_factory=dict)

    @property
    def guest_at_host(self) -> np.ndarray:
        """Guest vertex lying on each host curve vertex, shape (k,)."""
        return self.seam[self.host_hit]


@dataclass
class JoinResult:
    """The deformed guest and everything measured about the join.

    Attributes
    ----------
    host : Mesh
        The host, unchanged. Several host meshes are concatenated into one
        (vertices and faces in the order given; see :attr:`host_offsets`).
    guest : Mesh
        Deformed guest: original vertices first in original order, inserted
        seam vertices after. Face attribute ``area_ratio``; vertex attributes
        ``displacement`` (non-rigid, length unit), ``strain`` (mean of the
        incident edges' strains) and ``seam`` (bool).
    rest_guest : Mesh
        The guest before deformation, with the inserted seam vertices (same
        connectivity as ``guest``).
    seam : ndarray of int64, shape (s,)
        Guest seam vertices in curve order. With several seams: every
        seam's vertices, seam after seam (the concatenation of
        ``seams[i].seam``); the order of ``seam_targets`` and of
        ``solve(targets=...)``.
    host_curve : ndarray of int64, shape (k,)
        Host curve vertices in curve order. With several seams: the
        concatenation of ``seams[i].host_curve`` (not one polyline).
    seam_targets : ndarray, shape (s, 3)
        Where each seam vertex was held.
    closed : bool
        The curve is a loop. With several seams: every curve is a loop.
    area_ratio : ndarray, shape (m,)
        Deformed over rest area per guest face.
    converged : bool
    iterations : int
    energy : list of float
        Energy history (initial guess, then each iteration).
    counts : dict
        ``points``, ``hard`` and ``soft`` constraints counted per coordinate
        as the paper counts them, plus ``seam``, ``inserted``, ``faces``.
    timings : dict
        Seconds per phase.
    options : JoinOptions
    correspondence : Correspondence
        With several seams, the correspondence of all of them together:
        ``V``, ``F``, ``face_parent``, ``inserted_*`` describe the guest
        refined on every seam; ``seam``, ``targets``, ``seam_t``,
        ``host_edge_t`` are concatenated seam after seam, ``host_hit``
        indexes the concatenated ``seam`` and ``host_edge`` the
        concatenated ``host_curve`` (a segment never crosses from one seam
        to the next; use :attr:`seams` for per-seam curves).
    crease : ndarray, shape (k,)
        Crease angle (degrees) at each host curve vertex (concatenated over
        the seams).
    metrics : dict
        Plain-JSON join quality: seam gap, crease angles and the host's own
        dihedral angles near the seam, area ratio, edge and vertex strain,
        displacement, folds, weld counts and seam self-intersections (see
        ``docs/results.md``); ``metrics["seams"]`` repeats the seam gap,
        crease and host dihedral angles for each seam, the top-level values
        are over all seams (the largest relative gap, the mean over all seam
        vertices).
    stop_reason : str
        ``"tolerance"``, ``"max_iterations"`` or ``"time_limit"``.
    pairing : dict
        Rigid-fit residuals of the closed-curve start search (one seam;
        empty with several seams, see ``seams[i].pairing``).
    seams : list of JoinedSeam
        Each seam (one entry for a single-seam join), in the order given.
    host_offsets : ndarray of int64, shape (h + 1,)
        Host mesh ``i`` has the combined host vertices
        ``host_offsets[i]:host_offsets[i + 1]`` (``[0, n_h]`` for one host).
    merged : Welded
        Host and deformed guest welded into one mesh (computed on first use,
        then kept; see :func:`igljoin.weld.weld`).
    warnings : tuple of QualityWarning
        What is wrong with the join, if anything (computed on first use, then
        kept; see :func:`igljoin.quality.assess` and ``docs/warnings.md``).
        Empty for a clean join.
    """

    host: Mesh
    guest: Mesh
    rest_guest: Mesh
    seam: np.ndarray
    host_curve: np.ndarray
    seam_targets: np.ndarray
    closed: bool
    area_ratio: np.ndarray
    converged: bool
    iterations: int
    energy: list
    counts: dict
    timings: dict
    options: JoinOptions
    correspondence: Correspondence
    crease: np.ndarray
    metrics: dict = field(default_factory=dict)
    stop_reason: str = ""
    pairing: dict = field(default_factory=dict)
    seams: list = field(default_factory=list)
    host_offsets: np.ndarray | None = None
    _merged: Welded | None = field(default=None, init=False, repr=False, compare=False)
    _warnings: tuple | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def merged(self) -> Welded:
        """Host and deformed guest as one mesh with shared seam vertices (cached).

        Raises
        ------
        WeldError
            If the two cannot be welded into a clean oriented manifold.
        """
        if self._merged is None:
            self._merged = weld(self)
        return self._merged

    @property
    def guest_at_host(self) -> np.ndarray:
        """Guest vertex lying on each host curve vertex, shape (k,)."""
        return self.seam[self.correspondence.host_hit]

    @property
    def warnings(self) -> tuple[QualityWarning, ...]:
        """The join's quality warnings (cached; empty for a clean join).

        See :func:`igljoin.quality.assess`; ``docs/warnings.md`` lists the
        codes, their thresholds and what to do.
        """
        if self._warnings is None:
            self._warnings = assess(self)
        return self._warnings

    def measure_weld(self, rings: int = SELF_INTERSECTION_RINGS) -> dict:
        """Weld (kept as :attr:`merged`) and count self-intersections near the seam.

        Run by every join. A weld failure is recorded, not raised.

        Parameters
        ----------
        rings : int
            Faces of the welded mesh within this many rings of the seam are
            tested against each other (:func:`igljoin.metrics.ring_band`).

        Returns
        -------
        dict
            ``{"weld": {...}, "self_intersections": {...}}``, plain JSON:
            ``weld`` holds ``ok`` and, when welded, the counts of
            :meth:`Welded.summary`, otherwise ``error`` (the message);
            ``self_intersections`` holds ``pairs`` (intersecting face pairs),
            ``host_guest``, ``guest_guest``, ``host_host`` (the same pairs by
            the faces' sides), ``faces_tested``, ``rings``, ``per_seam`` (the
            pairs by the seam nearest to them) and ``centres`` (per seam, the
            mean centre of those pairs, or None); it is ``None`` when the weld
            failed.
        """
        try:
            welded = self.merged
        except WeldError as exc:
            return {"weld": {"ok": False, "error": str(exc)}, "self_intersections": None}
        F = welded.mesh.F
        band = ring_band(F, welded.seam, rings)
        pairs = self_intersections(welded.mesh.V, F, band)
        sides = welded.label[pairs].sum(axis=1)  # 0 host-host, 1 host-guest, 2 guest-guest
        centres = welded.mesh.V[F[pairs]].mean(axis=(1, 2))  # (p, 3): each pair's centre
        where = self._nearest_seams(centres)
        return {
            "weld": {"ok": True, **welded.summary()},
            "self_intersections": {
                "pairs": int(len(pairs)),
                "host_guest": int((sides == 1).sum()),
                "guest_guest": int((sides == 2).sum()),
                "host_host": int((sides == 0).sum()),
                "faces_tested": int(band.sum()),
                "rings": int(rings),
                # where: the pairs by the seam nearest to them, and per seam the mean
                # centre of its pairs (None without a pair)
                "per_seam": [int(c) for c in np.bincount(where, minlength=len(self.seams))],
                "centres": [
                    centres[where == i].mean(axis=0).tolist() if (where == i).any() else None
                    for i in range(len(self.seams))
                ],
            },
        }

    def _nearest_seams(self, points: np.ndarray) -> np.ndarray:
        """Index of the seam whose host curve is nearest to each point (shape (p,))."""
        if not len(points) or len(self.seams) < 2:
            return np.zeros(len(points), dtype=np.int64)
        dist = np.stack(
            [
                np.linalg.norm(
                    points[:, None, :] - self.host.V[sm.host_curve][None, :, :], axis=2
                ).min(axis=1)
                for sm in self.seams
            ],
            axis=1,
        )
        return np.argmin(dist, axis=1)

    def report(self) -> dict:
        """Plain-JSON summary of the join: warnings, counts, timings, convergence, metrics, options.

        ``json.dumps(result.report())`` always works: numpy values are
        converted and non-finite numbers become ``null``. ``"warnings"`` is
        the list of :attr:`warnings` as ``{"code", "message", "value",
        "threshold"}`` (empty for a clean join).
        """
        return plain_json(
            {
                "warnings": [w.to_json() for w in self.warnings],
                "closed": bool(self.closed),
                "converged": bool(self.converged),
                "stop_reason": self.stop_reason,
                "iterations": int(self.iterations),
                "energy": {"initial": float(self.energy[0]), "final": float(self.energy[-1])},
                "counts": {k: int(v) for k, v in self.counts.items()},
                "timings": {k: float(v) for k, v in self.timings.items()},
                "metrics": self.metrics,
                "options": self.options.to_json(),
                "pairing": {k: float(v) for k, v in self.pairing.items()},
                "seams": [
                    {
                        "host_index": int(sm.host_index),
                        "closed": bool(sm.closed),
                        "seam": int(len(sm.seam)),
                        "host_curve": int(len(sm.host_curve)),
                        "inserted": int(sm.inserted),
                        "pairing": {k: float(v) for k, v in sm.pairing.items()},
                    }
                    for sm in self.seams
                ],
            }
        )

    def save(
        self, folder: str | os.PathLike, *, merged: bool = True, formats=None
    ) -> dict[str, Path]:
        """Write the deformed guest, the welded mesh and the report into ``folder``.

        Parameters
        ----------
        folder : str or os.PathLike
            Created (with its parents) if missing. Existing files of the same
            names are replaced, each atomically: a file is either the complete
            new one or the old one.
        merged : bool
            Also write ``merged.ply``. Pass ``False`` to save a join whose
            weld fails (:class:`~igljoin.errors.WeldError`).
        formats : str or iterable of str, optional
            Mesh formats to write, e.g. ``("ply", "vtu")`` (the default,
            :data:`igljoin.io.DEFAULT_OUTPUT_FORMATS`), ``"ply,vtk"`` or
            ``["vtu"]``; any suffix :func:`~igljoin.io.write_mesh` writes.

        Returns
        -------
        dict of str to pathlib.Path
            ``{"guest": .../guest.ply, "merged": .../merged.ply,
            "guest_vtu": .../guest.vtu, "merged_vtu": .../merged.vtu,
            "report": .../report.json}`` (no ``"merged*"`` if not written):
            ``"guest"``/``"merged"`` name the file of the first format,
            ``"guest_<fmt>"``/``"merged_<fmt>"`` those of the others.

        Notes
        -----
        * ``guest.ply``: the deformed guest; vertex properties
          ``displacement``, ``strain``, ``seam``; face property ``area_ratio``.
        * ``merged.ply``: :attr:`merged` with its vertex properties ``seam``,
          ``source``, ``source_id``, ``strain``, ``displacement`` and face
          properties ``label``, ``source_face``, ``area_ratio``.
        * ``report.json``: :meth:`report` (which includes the options).
        * Both PLY files also carry ``quality`` properties, copies of the
          vertex ``displacement`` and the face ``area_ratio``: MeshLab reads
          only that property name (Filters > Color Creation > Colorize by
          vertex / face quality).
        * ``guest.vtu`` / ``merged.vtu``: the same meshes with every property
          as a named VTK array, which ParaView and VTK colour by (ParaView's
          PLY reader keeps no custom properties).

        PLY with float64 values, ASCII because the meshes have face
        properties (see :func:`~igljoin.io.write_mesh`): :func:`igljoin.read_mesh`
        and meshio return every property (exactly); MeshLab and pymeshlab
        load the geometry and the ``quality`` values (see ``docs/results.md``).
        """
        kinds = output_formats(DEFAULT_OUTPUT_FORMATS if formats is None else formats)
        out = Path(folder)
        if out.exists() and not out.is_dir():
            raise NotADirectoryError(
                f"cannot save into {out}: it is a file, not a folder; pass a folder path"
            )
        welded = None
        if merged:
            try:
                welded = self.merged
            except WeldError as exc:
                raise WeldError(
                    f"{exc} (to save the rest, call save(folder, merged=False))"
                ) from None
        out.mkdir(parents=True, exist_ok=True)
        paths = {}
        meshes = [("guest", self.guest)] + ([("merged", welded.mesh)] if welded else [])
        for kind, mesh in meshes:
            for i, fmt in enumerate(kinds):
                shown = _with_quality(mesh) if fmt == "ply" else mesh
                paths[kind if i == 0 else f"{kind}_{fmt}"] = write_mesh(
                    out / f"{kind}.{fmt}", shown
                )
        text = json.dumps(self.report(), indent=2, allow_nan=False) + "\n"
        paths["report"] = atomic_write_text(out / "report.json", text)
        return paths
