"""igljoin: smooth joining of a flexible guest mesh to a rigid host (GMP 2008, extended).

Quick start
-----------
>>> import igljoin
>>> s = igljoin.phantoms.paper_sample("end_to_end", "equal", resolution=0.4)
>>> res = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve)
>>> res.converged
True

``import igljoin`` is cheap: it loads no submodule. Each public name below
(``igljoin.join``, ``igljoin.read_mesh``, ``igljoin.phantoms``, ...) imports
its submodule on first use, so ``igljoin --version`` or ``igljoin info``
do not pay for the solver (numba, scipy) or for the optional parts
(pymeshlab cleanup, polyscope inspection, dask), which load only when used.
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import TYPE_CHECKING

__version__ = "0.1.0"

#: Public name -> submodule that defines it (imported on first access).
_LAZY = {
    "CaseSpec": "spec",
    "CleanReport": "clean",
    "ResampleReport": "clean",
    "clean": "clean",
    "diagnose": "clean",
    "load_case": "spec",
    "resample": "clean",
    "Curve": "boundary",
    "CurveError": "errors",
    "IgljoinError": "errors",
    "JoinOptions": "options",
    "JoinResult": "join",
    "JoinSolver": "join",
    "SolveProgress": "join",
    "Mesh": "mesh",
    "MeshError": "errors",
    "MeshReadError": "errors",
    "MissingExtraError": "errors",
    "OptionsError": "errors",
    "QualityWarning": "quality",
    "SolveError": "errors",
    "SpecError": "errors",
    "WeldError": "errors",
    "Welded": "weld",
    "as_mesh": "mesh",
    "boundary_loops": "boundary",
    "join": "join",
    "read_mesh": "io",
    "select_curve": "boundary",
    "stiffness_from_regions": "stiffness",
    "weld": "weld",
    "write_mesh": "io",
}

#: Submodules reachable as attributes (``igljoin.phantoms``) without an import statement,
#: as they were when ``import igljoin`` imported everything: every submodule but the
#: three whose name is a public function (``join``, ``clean``, ``weld``).
_SUBMODULES = (
    "atomic", "band_targets", "bandfit", "boundary", "cli", "coarse_kernels", "correspond",
    "crease", "demo", "errors", "frames", "host_values", "io", "join_terms", "kernels",
    "linsolve", "measure", "measure_join", "mesh", "metrics", "newton", "options", "outputs",
    "phantoms", "pipeline", "plain", "polyline", "quality", "result", "rotations",
    "seam_geometry", "seams", "solve", "spec", "start", "stiffness", "terms", "topology",
    "twolevel", "validate", "viz",
)  # fmt: skip

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
    "QualityWarning",
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

if TYPE_CHECKING:  # for type checkers and IDEs; at run time __getattr__ imports on demand
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
    from .quality import QualityWarning
    from .spec import CaseSpec, load_case
    from .stiffness import stiffness_from_regions
    from .weld import Welded, weld


def __getattr__(name: str):
    """Import the submodule behind a public name on first access (PEP 562)."""
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    elif name in _SUBMODULES:
        value = importlib.import_module(f".{name}", __name__)
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value  # later look-ups are plain attribute reads
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY, *_SUBMODULES})


class _Package(types.ModuleType):
    """The package module: keeps ``igljoin.join``, ``.clean``, ``.weld`` the functions.

    Importing a submodule binds it as an attribute of its package
    (``import igljoin.join`` sets ``igljoin.join`` to the module). Three
    public functions share their submodule's name; eagerly imported, the
    function was bound last and won. Imported lazily, the submodule may load
    first, so that binding is skipped here: the submodule stays reachable in
    ``sys.modules`` and through ``from igljoin.join import ...``.
    """

    def __setattr__(self, name: str, value) -> None:
        if isinstance(value, types.ModuleType) and _LAZY.get(name) == name:
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
