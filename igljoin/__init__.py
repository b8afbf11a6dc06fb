"""igljoin: smooth joining of a flexible guest mesh to a rigid host (GMP 2008, extended).

Quick start
-----------
>>> import igljoin
>>> s = igljoin.phantoms.paper_sample("end_to_end", "equal", resolution=0.4)
>>> res = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve)
>>> res.converged
True

Optional parts (pymeshlab cleanup, polyscope inspection, dask) are imported
only when used.
"""

from __future__ import annotations

from . import phantoms
from .boundary import Curve, boundary_loops, select_curve
from .clean import CleanReport, ResampleReport, clean, diagnose, resample
from .errors import (
    CurveError,
    IgljoinError,
    MeshError,
    MeshReadError,
    MissingExtraError,
    OptionsError,
    SolveError,
    SpecError,
    WeldError,
)
from .io import read_mesh, write_mesh
from .join import JoinResult, JoinSolver, SolveProgress, join
from .mesh import Mesh, as_mesh
from .options import JoinOptions
from .spec import CaseSpec, load_case
from .stiffness import stiffness_from_regions
from .weld import Welded, weld

__version__ = "0.1.0"

__all__ = [
    "CaseSpec",
    "CleanReport",
    "ResampleReport",
    "clean",
    "diagnose",
    "load_case",
    "resample",
    "Curve",
    "CurveError",
    "IgljoinError",
    "JoinOptions",
    "JoinResult",
    "JoinSolver",
    "SolveProgress",
    "Mesh",
    "MeshError",
    "MeshReadError",
    "MissingExtraError",
    "OptionsError",
    "SolveError",
    "SpecError",
    "WeldError",
    "Welded",
    "as_mesh",
    "boundary_loops",
    "join",
    "phantoms",
    "read_mesh",
    "select_curve",
    "stiffness_from_regions",
    "weld",
    "write_mesh",
]
