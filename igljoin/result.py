"""The outcome of a join: deformed guest, correspondence, measurements."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .correspond import Correspondence
from .mesh import Mesh
from .options import JoinOptions

__all__ = ["JoinResult"]


@dataclass
class JoinResult:
    """The deformed guest and everything measured about the join.

    Attributes
    ----------
    host : Mesh
        The host, unchanged.
    guest : Mesh
        Deformed guest: original vertices first in original order, inserted
        seam vertices after. Face attribute ``area_ratio``.
    rest_guest : Mesh
        The guest before deformation, with the inserted seam vertices (same
        connectivity as ``guest``).
    seam : ndarray of int64, shape (s,)
        Guest seam vertices in curve order.
    host_curve : ndarray of int64, shape (k,)
        Host curve vertices in curve order.
    seam_targets : ndarray, shape (s, 3)
        Where each seam vertex was held.
    closed : bool
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
    metrics : dict
        Seam gap, crease angles, area ratio, strain and displacement summaries, folds.
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

    @property
    def guest_at_host(self) -> np.ndarray:
        """Guest vertex lying on each host curve vertex, shape (k,)."""
        return self.seam[self.correspondence.host_hit]

    def report(self) -> dict:
        """Plain-JSON summary of the join (counts, timings, convergence, metrics)."""
        return {
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
        }
