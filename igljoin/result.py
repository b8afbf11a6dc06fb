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
from .measure import SELF_INTERSECTION_RINGS, guest_maps, weld_metrics
from .mesh import Mesh
from .options import JoinOptions
from .plain import plain_json
from .quality import QualityWarning, assess
from .weld import SeamRecord, Welded, weld

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
class JoinedSeam(SeamRecord):
    """One seam of a join: a guest curve held on a host curve.

    A :class:`igljoin.weld.SeamRecord` (``host_curve``, ``seam``,
    ``closed``, ``host_hit``, ``host_edge``, ``host_edge_t``: where the
    guest seam vertices lie on the host curve) with what the join made and
    measured of it.

    Attributes
    ----------
    host_curve : ndarray of int64, shape (k,)
        Host curve vertices in curve order, as indices into the combined
        host ``JoinResult.host``.
    seam : ndarray of int64, shape (s,)
        Guest seam vertices in curve order (indices into ``JoinResult.guest``).
    closed : bool
    host_hit, host_edge, host_edge_t : ndarray
        See :class:`igljoin.weld.SeamRecord`.
    host_index : int
        Which host mesh the curve is on (0 for a single host mesh).
    targets : ndarray, shape (s, 3)
        Where each seam vertex was held.
    inserted : int
        Guest vertices inserted on this seam.
    crease : ndarray, shape (k,)
        Crease angle (degrees) at each host curve vertex.
    pairing : dict
        Rigid-fit residuals of the start search (closed curves; see
        :func:`igljoin.correspond.pair_curves`).
    """

    host_index: int = 0
    targets: np.ndarray | None = None
    inserted: int = 0
    crease: np.ndarray | None = None
    pairing: dict = field(default_factory=dict)


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
    coarse_model : dict
        What the solve did with the coarse model of the ``preconditioner``
        option: ``"in_use"`` (the model preconditioned the steps to the
        solve's end), ``"builds"`` (its factorizations in this solve; 0 for
        a model kept from the solve before) and ``"fallback"`` (why
        ``"auto"`` went on with the factored form alone, or ``None``).
        ``{"in_use": False, "builds": 0, "fallback": None}`` where no model
        was asked for (``"factored"``, or ``"auto"`` below its size).
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
    seams: list
    seam_targets: np.ndarray
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
    host_offsets: np.ndarray | None = None
    coarse_model: dict = field(
        default_factory=lambda: {"in_use": False, "builds": 0, "fallback": None}
    )
    _merged: Welded | None = field(default=None, init=False, repr=False, compare=False)
    _warnings: tuple | None = field(default=None, init=False, repr=False, compare=False)

    # -- the single-seam view: every seam's values, seam after seam ---------------------------

    @property
    def seam(self) -> np.ndarray:
        """Guest seam vertices, every seam's in curve order, seam after seam, shape (s,)."""
        return np.concatenate([sm.seam for sm in self.seams])

    @property
    def host_curve(self) -> np.ndarray:
        """Host curve vertices, every seam's in curve order, seam after seam, shape (k,)."""
        return np.concatenate([sm.host_curve for sm in self.seams])

    @property
    def closed(self) -> bool:
        """Every curve is a loop."""
        return all(sm.closed for sm in self.seams)

    @property
    def pairing(self) -> dict:
        """Rigid-fit residuals of the closed-curve start search (one seam; else empty)."""
        return dict(self.seams[0].pairing) if len(self.seams) == 1 else {}

    @property
    def guest_at_host(self) -> np.ndarray:
        """Guest vertex lying on each host curve vertex, shape (k,)."""
        return np.concatenate([sm.guest_at_host for sm in self.seams])

    # -- the welded mesh ---------------------------------------------------------------------

    def weld(self, *, check: bool = True) -> Welded:
        """Host and deformed guest welded afresh (:func:`igljoin.weld.weld` of this result).

        Raises
        ------
        WeldError
            If the two cannot be welded into a clean oriented manifold.
        """
        strain, displacement = guest_maps(self.rest_guest.V, self.guest)
        return weld(
            self.host.V,
            self.host.F,
            self.guest.V,
            self.guest.F,
            self.seams,
            strain=strain,
            displacement=displacement,
            area_ratio=self.area_ratio,
            check=check,
        )

    @property
    def merged(self) -> Welded:
        """Host and deformed guest as one mesh with shared seam vertices (cached).

        Raises
        ------
        WeldError
            If the two cannot be welded into a clean oriented manifold.
        """
        if self._merged is None:
            self._merged = self.weld()
        return self._merged

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

        Run by every join: :func:`igljoin.measure.weld_metrics` of
        :attr:`merged` (``rings`` as there), or, when the weld fails,
        ``{"weld": {"ok": False, "error": message}, "self_intersections":
        None}`` (recorded, not raised).

        Parameters
        ----------
        rings : int
            Width of the tested band around the seam, in face rings.

        Returns
        -------
        dict
        """
        try:
            welded = self.merged
        except WeldError as exc:
            return {"weld": {"ok": False, "error": str(exc)}, "self_intersections": None}
        return weld_metrics(welded, self.host.V, [sm.host_curve for sm in self.seams], rings)

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
                "coarse_model": dict(self.coarse_model),
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
