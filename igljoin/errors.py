"""Exception types raised by igljoin.

Every error a user can cause is a :class:`ValueError` subclass (or an
:class:`OSError` for the file system) whose message names the problem and
the fix. ``assert`` is kept for internal invariants only.
"""

from __future__ import annotations


class IgljoinError(ValueError):
    """Base class of every input error igljoin raises."""


class MeshError(IgljoinError):
    """A mesh is malformed: wrong shapes, non-finite coordinates, bad faces."""


class MeshReadError(MeshError):
    """A file could not be read as a mesh (unknown format, truncated, garbage)."""


class CurveError(IgljoinError):
    """A boundary curve selection is invalid (not on a boundary, wrong loop...)."""


class OptionsError(IgljoinError):
    """A join option is out of range or of the wrong type."""


class SolveError(IgljoinError):
    """The deformation problem is ill-posed (e.g. a component no seam reaches)."""


class WeldError(IgljoinError):
    """Welding host and guest would produce a non-manifold or broken mesh."""


class SpecError(IgljoinError):
    """A case folder or its ``join.toml`` is invalid."""


class MissingExtraError(ImportError):
    """An optional dependency is not installed; the message names the extra."""


def missing_extra(package: str, extra: str, feature: str) -> MissingExtraError:
    """Build the error for a missing optional dependency.

    Parameters
    ----------
    package : str
        Import name of the missing package (e.g. ``"polyscope"``).
    extra : str
        Name of the igljoin extra that installs it (e.g. ``"viz"``).
    feature : str
        What the user tried to use.

    Returns
    -------
    MissingExtraError
    """
    return MissingExtraError(
        f"{feature} needs the optional package '{package}', which is not installed; "
        f"install it with: pip install 'igljoin[{extra}]'"
    )


class OutputError(IgljoinError):
    """An output path would replace or delete something igljoin did not write."""
