"""Reading and writing triangle meshes: OBJ, OFF, PLY, STL; VTU and legacy VTK output.

Formats are chosen from the file suffix (case-insensitive); each has its own
module (:mod:`.obj`, :mod:`.off`, :mod:`.ply`, :mod:`.stl`, :mod:`.vtk`),
imported on first use.

* PLY is read and written by igljoin's own code (ASCII and binary, any mix
  of property types), with vectorised paths for binary elements of
  fixed-size rows and for plain ASCII files. Extra scalar vertex and face
  properties become :attr:`Mesh.vertex_attributes` /
  :attr:`Mesh.face_attributes`.
* OBJ, OFF and STL are parsed with vectorised numpy, block by block, with a
  record-by-record reference parser for unusual blocks that gives every
  check and message (with line numbers). libigl's ``read_triangle_mesh`` is
  deliberately not used: it aborts the process on some PLY files and, on
  malformed OBJ/OFF/STL input, silently returns nonsense.
* ``.vtu`` and ``.vtk`` are written through :mod:`meshio` with every
  attribute as a named array (for ParaView and VTK).

Every malformed input raises :class:`~igljoin.errors.MeshReadError` whose
message names the file, the problem and the fix; a missing file raises
:class:`FileNotFoundError`. The size guard (``igljoin.mesh.MAX_ELEMENTS``) is
applied to the counts a header declares before anything is read, and to
text files while they are read, which is done in blocks of bounded size.
Input files are only ever opened read-only. Output goes through
:func:`~igljoin.atomic.atomic_path`, so a failed write never leaves a
partial file.
"""

from __future__ import annotations

import errno
import importlib
import os
import stat
from pathlib import Path

import numpy as np

from ..atomic import atomic_path
from ..errors import MeshError, MeshReadError, OptionsError
from ..mesh import Mesh, as_mesh
from ._common import SUPPORTED_SUFFIXES, WRITE_SUFFIXES, Arrays, error, supported

__all__ = [
    "read_mesh",
    "write_mesh",
    "output_formats",
    "SUPPORTED_SUFFIXES",
    "WRITE_SUFFIXES",
    "DEFAULT_OUTPUT_FORMATS",
]

_MODULES = {
    ".obj": "obj",
    ".off": "off",
    ".ply": "ply",
    ".stl": "stl",
    ".vtu": "vtk",
    ".vtk": "vtk",
}


def _module(suffix: str):
    return importlib.import_module(f".{_MODULES[suffix]}", __name__)


def _as_path(path, what: str, exc: type) -> Path:
    """``path`` as a :class:`Path` (bytes are decoded as the OS does); refuse other types."""
    if isinstance(path, bytes):
        path = os.fsdecode(path)
    if not isinstance(path, (str, os.PathLike)):
        raise exc(
            f"{what} needs a file path (str, bytes or os.PathLike), not {type(path).__name__}"
        )
    file = Path(path)
    if "\0" in str(file):
        raise exc(
            f"{what}: the path {str(file)!r} contains a NUL byte, which no file name can hold; "
            "check how the path was built"
        )
    return file


def _check_input_file(path: Path) -> None:
    """Raise unless ``path`` is an existing, non-empty regular file."""
    try:
        st = path.stat()
    except FileNotFoundError:
        where = "" if path.is_absolute() else f" (relative to {Path.cwd()})"
        raise FileNotFoundError(
            errno.ENOENT,
            f"mesh file not found: {path}{where}; check the path and its spelling",
            str(path),
        ) from None
    if stat.S_ISDIR(st.st_mode):
        raise error(path, "is a directory, not a mesh file", f"pass a file ending in {supported()}")
    if not stat.S_ISREG(st.st_mode):
        raise error(path, "is not a regular file", "pass a mesh file saved on disk")
    if st.st_size == 0:
        raise error(path, "is empty (0 bytes)", "re-export the mesh; the file holds no data")


def _format_of(path: Path) -> str:
    """Return the lower-case suffix of ``path`` or raise for an unknown one."""
    suffix = path.suffix.lower()
    if suffix not in SUPPORTED_SUFFIXES:
        shown = repr(path.suffix) if path.suffix else "no suffix"
        also = (
            " (igljoin writes .vtu/.vtk but reads only these)" if suffix in WRITE_SUFFIXES else ""
        )
        raise error(
            path,
            f"has {shown}, which is not a supported mesh format",
            f"use one of the supported suffixes {supported()}{also} (convert the file first)",
        )
    return suffix


def _build_mesh(path: Path, arrays: Arrays, name: str) -> Mesh:
    """Check for an empty surface and validate, naming the file in every error."""
    V, F, vattrs, fattrs = arrays
    if V.shape[0] == 0:
        raise error(path, "has no vertices", "the file holds no geometry; re-export the mesh")
    if F.shape[0] == 0:
        raise error(
            path,
            "has no faces; igljoin needs a triangle surface",
            f"the file holds only {V.shape[0]} vertices (a point cloud); "
            "export the surface with its faces",
        )
    try:
        return Mesh(V, F, vattrs, fattrs, name=name)
    except MeshReadError:
        raise
    except MeshError as exc:
        raise MeshReadError(
            f"{path}: the file was parsed but does not hold a valid mesh: {exc}"
        ) from None


def read_mesh(path: str | os.PathLike, *, name: str | None = None) -> Mesh:
    """Read a triangle mesh from an OBJ, OFF, PLY or STL file.

    Parameters
    ----------
    path : str, bytes or os.PathLike
        The file. The format comes from its suffix (case-insensitive):
        ``.obj``, ``.off``, ``.ply`` or ``.stl``. It is opened read-only.
    name : str, optional
        Name of the returned mesh, used in error messages; defaults to the
        file name without its suffix.

    Returns
    -------
    Mesh
        ``V`` of shape (n, 3) float64 and ``F`` of shape (m, 3) int64.
        Polygons with more than 3 vertices (OBJ, OFF, PLY) are split into
        triangle fans ``(v0, v_k, v_k+1)``. For PLY, every scalar vertex
        property other than ``x, y, z`` (normals, colours, quality, ...)
        becomes ``vertex_attributes[name]`` of shape (n,) float64, and every
        scalar face property becomes ``face_attributes[name]`` of shape (m,)
        float64 (repeated for each triangle of a split polygon); list
        properties other than the face indices are ignored. STL corners with
        exactly equal coordinates are merged into one vertex, so the mesh is
        connected. OBJ texture coordinates, normals, groups and materials
        are ignored.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    MeshReadError
        If ``path`` is not a path, is a directory or is empty, has an
        unsupported suffix, is not in the format its suffix claims, is
        truncated or corrupt, has no faces, declares or holds more vertices
        or faces than ``igljoin.mesh.MAX_ELEMENTS``, or holds an invalid mesh
        (e.g. NaN coordinates or face indices out of range). The message
        names the file, the problem and the fix (with the line number for
        text formats where one helps).

    Examples
    --------
    >>> mesh = read_mesh("host.ply")  # doctest: +SKIP
    >>> mesh.V.shape, mesh.F.shape  # doctest: +SKIP
    ((1872, 3), (3022, 3))
    """
    file = _as_path(path, "read_mesh", MeshReadError)
    _check_input_file(file)
    reader = _module(_format_of(file)).read
    with np.errstate(invalid="ignore", over="ignore"):  # NaN/inf are reported by validation
        arrays = reader(file)
    return _build_mesh(file, arrays, name if name is not None else file.stem)


# --------------------------------------------------------------------------- writers


def write_mesh(path: str | os.PathLike, mesh: Mesh, *, binary: bool | None = None) -> Path:
    """Write a triangle mesh to an OBJ, OFF, PLY, STL, VTU or VTK file, atomically.

    Parameters
    ----------
    path : str, bytes or os.PathLike
        Output file; the format comes from its suffix (case-insensitive):
        ``.obj``, ``.off``, ``.ply``, ``.stl``, ``.vtu`` or ``.vtk``. Its
        directory must exist. An existing file is replaced only once the new
        one is completely written.
    mesh : Mesh or tuple of (array_like (n, 3), array_like (m, 3))
        The mesh to write.
    binary : bool, optional
        Binary or ASCII encoding for PLY, STL, VTU and VTK (OBJ and OFF are
        always text). By default everything is binary except a PLY file of a
        mesh with face attributes, which is ASCII: meshio (5.3.5) misreads
        per-face properties of binary PLY, while every PLY reader reads them
        from ASCII.

    Returns
    -------
    pathlib.Path
        The written file.

    Raises
    ------
    MeshError
        If the suffix is not supported, an attribute cannot be stored
        (non-numeric dtype, or a PLY name clashing with another property),
        or binary STL cannot hold the coordinates (beyond float32's range).
    FileNotFoundError
        If the output directory does not exist.
    OSError
        On file-system failures; a full disk gives a message that says so.
        No partial file is left behind in any case.

    Notes
    -----
    * PLY keeps attributes: ``x, y, z`` and float attributes are stored as
      float64 (exact round trip, ``%.17g`` in ASCII), integer attributes as
      int32 (float64 if a value does not fit in int32), bool attributes as
      uint8. An attribute of shape (n, k) is stored as the properties
      ``name_0 .. name_{k-1}`` (read back as separate scalar attributes);
      shape (n, k, l, ...) is flattened the same way. Faces are
      ``property list uchar int vertex_indices``.
    * VTU (XML, zlib-compressed binary) and legacy VTK (version 4.2, which
      every VTK and ParaView reads) keep every attribute as a named array of
      its own dtype (bool as uint8) and shape ((n, k) as k components).
    * OBJ, OFF and STL cannot hold attributes: they are silently dropped.
    * OBJ, OFF and ASCII STL write coordinates with 17 significant digits, so
      they read back exactly; binary STL stores float32 coordinates and
      repeats shared vertices per triangle (they are merged again on reading).
    """
    target = _as_path(path, "write_mesh", MeshError)
    suffix = target.suffix.lower()
    if suffix not in WRITE_SUFFIXES:
        raise MeshError(
            f"cannot write {target}: unsupported suffix {target.suffix or '(none)'!r}; "
            f"use one of {supported(WRITE_SUFFIXES)}"
        )
    m = as_mesh(mesh)
    module = _module(suffix)
    if suffix == ".ply":
        module.check_writable(m)
        as_binary = not m.face_attributes if binary is None else bool(binary)
    elif suffix in (".vtu", ".vtk"):
        module.check_writable(m)
        as_binary = True if binary is None else bool(binary)
    else:
        as_binary = True if binary is None else bool(binary)
    if suffix == ".stl" and as_binary:
        module.check_binary_range(target, m)
    with atomic_path(target) as tmp:
        if suffix in (".obj", ".off"):
            module.write(tmp, m)
        elif suffix in (".vtu", ".vtk"):
            module.write(tmp, m, suffix, binary=as_binary)
        else:
            module.write(tmp, m, as_binary)
    return target


#: Formats that :meth:`igljoin.JoinResult.save`, ``igljoin join`` and
#: ``igljoin batch`` write by default: PLY (exact, read by igljoin, MeshLab
#: and meshio) and VTU (every attribute as a named array, for ParaView/VTK).
DEFAULT_OUTPUT_FORMATS = ("ply", "vtu")


def output_formats(formats) -> tuple[str, ...]:
    """Validate output format names.

    Parameters
    ----------
    formats : str or iterable of str
        Names such as ``"ply"`` or ``".vtu"`` (case-insensitive), or one
        comma-separated string such as ``"ply,vtu"``.

    Returns
    -------
    tuple of str
        Lower-case names without the dot, in the given order, without repeats.

    Raises
    ------
    OptionsError
        If a name is not a format :func:`write_mesh` writes, or none is given.
    """
    names = formats.split(",") if isinstance(formats, str) else formats
    known = [s[1:] for s in WRITE_SUFFIXES]
    try:
        cleaned = [str(n).strip().lower().lstrip(".") for n in names]
    except TypeError:
        raise OptionsError(
            f"output formats must be names such as 'ply,vtu', not {type(formats).__name__}"
        ) from None
    out: list[str] = []
    for name in cleaned:
        if name not in known:
            raise OptionsError(
                f"unknown output format {name!r}; choose from {', '.join(known)} (e.g. 'ply,vtu')"
            )
        if name not in out:
            out.append(name)
    if not out:
        raise OptionsError(f"no output format given; choose from {', '.join(known)}")
    return tuple(out)
