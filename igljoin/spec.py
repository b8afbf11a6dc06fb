"""Case folders: one join per folder, described by ``join.toml``.

A case folder holds the host mesh (``host.*``), the guest mesh (``guest.*``)
— any format :func:`igljoin.read_mesh` reads — and an optional ``join.toml``
naming the curves to join and the options. The format is documented with a
complete example in ``docs/pipelines.md``; in short::

    description = "coronary button, equal length"   # free text, optional
    host = "host.ply"        # optional; default: the only host.* file
    guest = "guest.obj"      # optional; default: the only guest.* file

    [host_curve]             # igljoin.Curve: indices | start/end/via | loop
    loop = 0

    [guest_curve]
    start = [1.0, 2.0, 3.0]  # a point snaps to the nearest boundary vertex

    [options]                # igljoin.JoinOptions keys, plus cleanup and resample
    smooth = true
    stiffness = "stiffness.npy"   # or an inline array
    cleanup = true                # or a [options.cleanup] table
    resample = true               # or a [options.resample] table

Specs are data: TOML parsed with :mod:`tomllib`, never evaluated. Unknown
keys are rejected with the list of valid ones, and every path must resolve
(symlinks included) inside the case folder. All problems raise
:class:`~igljoin.errors.SpecError` naming the file, the key and the fix.
"""

from __future__ import annotations

import dataclasses
import errno
import math
import os
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .boundary import Curve
from .clean import (
    MAX_HOLE_EDGES,
    MIN_COMPONENT_FACES,
    RESAMPLE_ITERATIONS,
    SLIVER_RATIO,
    clean_setting_problem,
    resample_setting_problem,
)
from .errors import OptionsError, SpecError
from .io import SUPPORTED_SUFFIXES
from .options import JoinOptions, new_names
from .outputs import file_sha256

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    try:
        import tomli as tomllib
    except ImportError:  # pragma: no cover
        tomllib = None

__all__ = [
    "SPEC_FILE",
    "CaseSpec",
    "CleanupSpec",
    "ResampleSpec",
    "discover_cases",
    "file_sha256",
    "load_case",
    "parse_options",
]

#: Name of the spec file inside a case folder.
SPEC_FILE = "join.toml"

_TOP_KEYS = ("description", "host", "guest", "host_curve", "guest_curve", "options")
_CURVE_KEYS = ("indices", "start", "end", "via", "loop", "closed")
_STIFFNESS_SUFFIXES = (".npy", ".txt", ".csv")


def _join_option_names() -> tuple[str, ...]:
    return tuple(f.name for f in dataclasses.fields(JoinOptions))


def _check(problem: tuple[str, Any, str] | None, what: str) -> None:
    if problem is not None:
        name, value, requirement = problem
        raise OptionsError(f"{what}: {name} = {_short(value)} {requirement}")


def _check_switches(spec: Any, names: tuple[str, ...], what: str) -> None:
    for name in names:
        value = getattr(spec, name)
        if not isinstance(value, (bool, np.bool_)):
            raise OptionsError(f"{what}: {name} = {_short(value)} must be true or false")
        object.__setattr__(spec, name, bool(value))


@dataclass(frozen=True)
class CleanupSpec:
    """Mesh repair before joining (see :func:`igljoin.clean.clean`).

    The defaults are :func:`~igljoin.clean.clean`'s own, and the settings are
    checked by the rule :func:`~igljoin.clean.clean` applies
    (:func:`igljoin.clean.clean_setting_problem`) when the spec is built.

    Parameters
    ----------
    host, guest : bool
        Which meshes to clean (both by default).
    close_holes : bool
        Fill small holes, keeping the curve to be joined open.
    max_hole_edges : int
        Largest hole filled, in boundary edges (3 to 2,147,483,647).
    sliver_ratio : float
        Aspect ratio (``2 r / R``) below which a face is a sliver, in [0, 1).
    min_component_faces : int
        Loose components with fewer faces are removed (0 keeps all).

    Raises
    ------
    OptionsError
        If a setting is out of range or of the wrong type.
    """

    host: bool = True
    guest: bool = True
    close_holes: bool = False
    max_hole_edges: int = MAX_HOLE_EDGES
    sliver_ratio: float = SLIVER_RATIO
    min_component_faces: int = MIN_COMPONENT_FACES

    def __post_init__(self) -> None:
        _check_switches(self, ("host", "guest", "close_holes"), "cleanup")
        _check(
            clean_setting_problem(self.max_hole_edges, self.sliver_ratio, self.min_component_faces),
            "cleanup",
        )
        for name in ("max_hole_edges", "min_component_faces"):
            object.__setattr__(self, name, int(getattr(self, name)))
        object.__setattr__(self, "sliver_ratio", float(self.sliver_ratio))

    def clean_kwargs(self) -> dict:
        """Keyword arguments of :func:`igljoin.clean.clean`."""
        return {
            "close_holes": self.close_holes,
            "max_hole_edges": self.max_hole_edges,
            "sliver_ratio": self.sliver_ratio,
            "min_component_faces": self.min_component_faces,
        }


@dataclass(frozen=True)
class ResampleSpec:
    """Guest resampling before joining (see :func:`igljoin.clean.resample`).

    Checked by :func:`igljoin.clean.resample_setting_problem`, the rule
    :func:`~igljoin.clean.resample` applies, when the spec is built.

    Parameters
    ----------
    target_edge : float, optional
        Wanted guest edge length (> 0); ``None`` (default) takes the mean
        edge length of the host curve being joined.
    iterations : int
        Isotropic remeshing iterations (1 to 100; the default is
        :func:`~igljoin.clean.resample`'s).

    Raises
    ------
    OptionsError
        If a setting is out of range or of the wrong type.
    """

    target_edge: float | None = None
    iterations: int = RESAMPLE_ITERATIONS

    def __post_init__(self) -> None:
        target = 1.0 if self.target_edge is None else self.target_edge
        _check(resample_setting_problem(target, self.iterations), "resample")
        if self.target_edge is not None:
            object.__setattr__(self, "target_edge", float(self.target_edge))
        object.__setattr__(self, "iterations", int(self.iterations))


@dataclass(frozen=True)
class CaseSpec:
    """One join to run: input files, curves and options.

    Build it with :func:`load_case` (from a case folder) or :meth:`make`.

    Attributes
    ----------
    name : str
        Case name (the folder name).
    folder : pathlib.Path or None
        Resolved case folder (``None`` for a case built by :meth:`make`).
    host, guest : pathlib.Path
        Resolved mesh files.
    host_curve, guest_curve : igljoin.Curve
        The curves to join.
    options : igljoin.JoinOptions
        The join options, validated (``stiffness`` loaded as an array).
    stiffness_file : pathlib.Path or None
        File the stiffness was loaded from.
    cleanup : CleanupSpec or None
    resample : ResampleSpec or None
    spec_file : pathlib.Path or None
        The ``join.toml`` read (``None`` if the folder has none).
    description : str
    """

    name: str
    folder: Path | None
    host: Path
    guest: Path
    host_curve: Curve = field(default_factory=Curve)
    guest_curve: Curve = field(default_factory=Curve)
    options: JoinOptions = field(default_factory=JoinOptions)
    stiffness_file: Path | None = None
    cleanup: CleanupSpec | None = None
    resample: ResampleSpec | None = None
    spec_file: Path | None = None
    description: str = ""

    @classmethod
    def make(
        cls,
        host: str | os.PathLike,
        guest: str | os.PathLike,
        host_curve: Any = None,
        guest_curve: Any = None,
        options: Mapping | None = None,
        *,
        name: str | None = None,
    ) -> CaseSpec:
        """A case from two mesh files (no case folder; paths are not confined).

        Parameters
        ----------
        host, guest : str or os.PathLike
            Mesh files.
        host_curve, guest_curve : Curve, mapping or None
            Curve specifications (mappings use the ``[host_curve]`` keys).
        options : mapping, optional
            The ``[options]`` table: JoinOptions keys plus ``cleanup`` and
            ``resample``; a ``stiffness`` string is a file path relative to
            the working directory.
        name : str, optional
            Case name; defaults to the guest file's stem.

        Returns
        -------
        CaseSpec

        Raises
        ------
        FileNotFoundError
            If a mesh file does not exist.
        SpecError
            If a curve or an option is invalid.
        """
        where = "arguments"
        for role, path in (("host", host), ("guest", guest)):
            if not Path(path).is_file():
                raise FileNotFoundError(
                    errno.ENOENT,
                    f"{role} mesh file not found: {path}; check the path and its spelling",
                    str(path),
                )
        hc = host_curve if isinstance(host_curve, Curve) else _curve(host_curve, where, "host")
        gc = guest_curve if isinstance(guest_curve, Curve) else _curve(guest_curve, where, "guest")
        parsed = parse_options(dict(options or {}), where=where, base=Path.cwd(), folder=None)
        return cls._checked(
            where,
            parsed,
            name=name or Path(guest).stem,
            folder=None,
            host=Path(host),
            guest=Path(guest),
            host_curve=hc,
            guest_curve=gc,
        )

    @classmethod
    def _checked(cls, where: str, parsed: tuple, **fields: Any) -> CaseSpec:
        """A spec of ``fields`` and the parsed ``[options]`` (:func:`parse_options`), checked.

        Checks what needs the whole spec: a resampled guest needs curves that
        survive resampling.
        """
        opts, stiffness_file, cleanup, resample = parsed
        spec = cls(
            **fields,
            options=opts,
            stiffness_file=stiffness_file,
            cleanup=cleanup,
            resample=resample,
        )
        _check_resample_curve(spec, where)
        return spec

    def __post_init__(self) -> None:
        for name, kind in (
            ("options", JoinOptions),
            ("cleanup", CleanupSpec),
            ("resample", ResampleSpec),
        ):
            value = getattr(self, name)
            if not isinstance(value, kind) and not (value is None and name != "options"):
                raise SpecError(
                    f"CaseSpec {name} must be a {kind.__name__}"
                    + ("" if name == "options" else " or None")
                    + f", got {type(value).__name__}; build the case with load_case or "
                    "CaseSpec.make"
                )

    def join_options(self) -> JoinOptions:
        """The validated :class:`igljoin.JoinOptions` of this case (:attr:`options`)."""
        return self.options

    def input_files(self) -> dict[str, Path]:
        """Every file the case reads: ``host``, ``guest``, ``spec`` and ``stiffness``."""
        files = {"host": self.host, "guest": self.guest}
        if self.spec_file is not None:
            files["spec"] = self.spec_file
        if self.stiffness_file is not None:
            files["stiffness"] = self.stiffness_file
        return files

    def input_hashes(self) -> dict[str, dict]:
        """``{role: {"file": name, "sha256": hex}}`` of :meth:`input_files`."""
        return {
            role: {"file": self._shown(path), "sha256": file_sha256(path)}
            for role, path in self.input_files().items()
        }

    def _shown(self, path: Path) -> str:
        if self.folder is not None:
            try:
                return path.relative_to(self.folder).as_posix()
            except ValueError:
                pass
        return str(path)

    def to_json(self) -> dict:
        """The effective spec as plain JSON (every option, defaults included).

        File paths are relative to the case folder, so the result does not
        depend on where the folder lives; it is what ``--resume`` compares.
        """
        return {
            "name": self.name,
            "description": self.description,
            "host": self._shown(self.host),
            "guest": self._shown(self.guest),
            "host_curve": _curve_json(self.host_curve),
            "guest_curve": _curve_json(self.guest_curve),
            "options": self.options.to_json(),
            "stiffness_file": None
            if self.stiffness_file is None
            else self._shown(self.stiffness_file),
            "cleanup": None if self.cleanup is None else dataclasses.asdict(self.cleanup),
            "resample": None if self.resample is None else dataclasses.asdict(self.resample),
        }


# --------------------------------------------------------------------------- helpers


def _curve_json(c: Curve) -> dict:
    out = {}
    for key in _CURVE_KEYS:
        value = getattr(c, key)
        if value is None:
            continue
        out[key] = np.asarray(value).tolist() if not isinstance(value, (bool, int)) else value
    return out


def _unknown(keys, valid, where: str, what: str) -> None:
    unknown = sorted(set(keys) - set(valid))
    if unknown:
        raise SpecError(
            f"{where}: unknown {what} {', '.join(map(repr, unknown))}; valid keys are "
            f"{', '.join(valid)}"
        )


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


#: Largest integer a spec may give (vertex, loop, iteration counts); beyond it is a typo.
MAX_SPEC_INT = 2**31 - 1


def _is_number(v: Any) -> bool:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return False
    try:
        return math.isfinite(v)  # an int beyond float range raises OverflowError
    except OverflowError:
        return False


def _big_int(value: Any, where: str, key: str) -> None:
    if _is_int(value) and value > MAX_SPEC_INT:
        raise SpecError(
            f"{where}: {key} = {_short(value)} is too large; it must be at most {MAX_SPEC_INT:,}"
        )


def _short(value: Any) -> str:
    """``repr`` of a value, cut to 60 characters (a 400-digit integer stays readable)."""
    text = repr(value)
    return text if len(text) <= 60 else f"{text[:40]}... ({len(text)} characters)"


def _vertex(value: Any, where: str, key: str) -> Any:
    """A vertex index (int >= 0) or a point [x, y, z] from TOML."""
    _big_int(value, where, key)
    if _is_int(value):
        if value < 0:
            raise SpecError(f"{where}: {key} = {value} must be a vertex index >= 0 or [x, y, z]")
        return int(value)
    if isinstance(value, (list, tuple)) and len(value) == 3 and all(map(_is_number, value)):
        return np.array(value, dtype=np.float64)
    raise SpecError(
        f"{where}: {key} = {value!r} must be a vertex index (an integer) or a point "
        "[x, y, z] of three numbers"
    )


def _curve(raw: Any, where: str, role: str) -> Curve:
    """Parse a ``[host_curve]``/``[guest_curve]`` table into a :class:`Curve`."""
    table = f"{where}: [{role}_curve]"
    if raw is None:
        return Curve()
    if not isinstance(raw, Mapping):
        raise SpecError(
            f"{table} must be a table such as {{ loop = 0 }}, got {raw!r}; valid keys are "
            f"{', '.join(_CURVE_KEYS)}"
        )
    _unknown(raw, _CURVE_KEYS, table, "curve keys")
    kw: dict[str, Any] = {}
    if "indices" in raw:
        idx = raw["indices"]
        if isinstance(idx, list):
            for i in idx:
                _big_int(i, table, "indices")
        if not isinstance(idx, list) or not idx or not all(_is_int(i) and i >= 0 for i in idx):
            raise SpecError(
                f"{table}: indices must be a non-empty list of vertex indices (integers >= 0)"
            )
        others = [k for k in ("start", "end", "via", "loop") if k in raw]
        if others:
            raise SpecError(
                f"{table}: give either indices or {'/'.join(others)}, not both (indices list "
                "the whole curve)"
            )
        kw["indices"] = np.array(idx, dtype=np.int64)
    for key in ("start", "end", "via"):
        if key in raw:
            kw[key] = _vertex(raw[key], table, key)
    if "loop" in raw:
        _big_int(raw["loop"], table, "loop")
        if not _is_int(raw["loop"]) or raw["loop"] < 0:
            raise SpecError(f"{table}: loop = {raw['loop']!r} must be a loop index (integer >= 0)")
        kw["loop"] = int(raw["loop"])
    if "closed" in raw:
        if not isinstance(raw["closed"], bool):
            raise SpecError(f"{table}: closed = {raw['closed']!r} must be true or false")
        kw["closed"] = raw["closed"]
    return Curve(**kw)


def _uses_indices(c: Curve) -> list[str]:
    keys = ["indices"] if c.indices is not None else []
    keys += [
        k for k in ("start", "end", "via") if getattr(c, k) is not None and _is_int(getattr(c, k))
    ]
    return keys


def _check_resample_curve(spec: CaseSpec, where: str) -> None:
    if spec.resample is None:
        return
    if spec.options.stiffness is not None:
        raise SpecError(
            f"{where}: stiffness gives one value per vertex or face of the guest as read, but "
            "resample remeshes the guest; drop one of the two (resample the guest beforehand "
            "with `igljoin clean --resample` and compute the stiffness on the result)"
        )
    keys = _uses_indices(spec.guest_curve)
    if keys:
        raise SpecError(
            f"{where}: [guest_curve] uses vertex indices ({', '.join(keys)}) but resample "
            "renumbers the guest's vertices; give the guest curve by loop index or by points "
            "[x, y, z] for start/end/via, or switch resample off"
        )


def _inside(folder: Path, value: Any, where: str, key: str) -> Path:
    """Resolve a path named in a spec; it must stay inside ``folder`` (symlinks resolved)."""
    if not isinstance(value, str) or not value:
        raise SpecError(f"{where}: {key} = {_short(value)} must be a file name (a string)")
    if "\0" in value:
        raise SpecError(
            f"{where}: {key} = {_short(value)} contains a NUL character, which no file name "
            "can hold; fix the name"
        )
    candidate = Path(value)
    if not candidate.is_absolute():
        candidate = folder / candidate
    try:
        resolved = candidate.resolve(strict=False)
    except (RuntimeError, OSError) as exc:  # a symbolic link loop (RuntimeError on 3.11)
        raise SpecError(
            f"{where}: {key} = {value!r} cannot be resolved ({exc}); it is a symbolic link "
            "that loops or is unreadable: replace it with the file"
        ) from None
    if not resolved.is_relative_to(folder):
        raise SpecError(
            f"{where}: {key} = {value!r} resolves to {resolved}, outside the case folder "
            f"{folder}; keep every file of a case inside its folder (copy the file in; a "
            "symbolic link pointing outside is refused too)"
        )
    if not resolved.is_file():
        raise SpecError(f"{where}: {key} = {value!r}: no such file in the case folder {folder}")
    return resolved


def _load_stiffness(path: Path, where: str) -> np.ndarray:
    suffix = path.suffix.lower()
    if suffix not in _STIFFNESS_SUFFIXES:
        raise SpecError(
            f"{where}: stiffness file {path.name} has an unsupported suffix; use "
            f"{', '.join(_STIFFNESS_SUFFIXES)} (one value per guest vertex or face)"
        )
    if suffix == ".npy":
        _check_npy_header(path, where)
    try:
        if suffix == ".npy":
            k = np.load(path, allow_pickle=False)
        else:
            k = np.loadtxt(path, delimiter="," if suffix == ".csv" else None, ndmin=1)
        k = np.asarray(k, dtype=np.float64).reshape(-1)
    except (OSError, ValueError, TypeError) as exc:
        raise SpecError(
            f"{where}: cannot read the stiffness file {path.name} ({exc}); save one number per "
            "guest vertex or face with numpy.save or as plain text"
        ) from None
    return k


#: Most stiffness values a file may hold (one per guest vertex or face; the mesh limit).
MAX_STIFFNESS_VALUES = 20_000_000


def _check_npy_header(path: Path, where: str) -> None:
    """Refuse a ``.npy`` whose header claims more values than the file holds or is sensible.

    Read before :func:`numpy.load`, which would otherwise allocate what the
    header claims (10^12 values: 7 TiB).
    """
    try:  # a memory map reads the header only; it fails if the data are shorter
        view = np.load(path, mmap_mode="r", allow_pickle=False)
        shape, itemsize = view.shape, view.dtype.itemsize
        del view
        data_bytes = path.stat().st_size
    except (OSError, ValueError, TypeError) as exc:
        shape, itemsize, data_bytes = None, 0, 0
        reason = str(exc)
    if shape is None:
        raise SpecError(
            f"{where}: the stiffness file {path.name} is not a valid .npy file of its declared "
            f"size ({reason[:200]}); the file is truncated or corrupt: save it again with "
            "numpy.save"
        )
    count = math.prod(shape)
    if count > MAX_STIFFNESS_VALUES or count * itemsize > data_bytes:
        raise SpecError(
            f"{where}: the stiffness file {path.name} claims {count:,} values of {itemsize} "
            f"bytes but the file has {data_bytes:,} bytes (at most {MAX_STIFFNESS_VALUES:,} "
            "values are read); the file is truncated or corrupt: save it again with numpy.save"
        )


def _bool(value: Any, where: str, key: str) -> bool:
    if not isinstance(value, bool):
        raise SpecError(f"{where}: {key} = {value!r} must be true or false")
    return value


def _table(raw: Any, kind: type, where: str, key: str, shorthand: str) -> Mapping | None:
    """The ``[options.KEY]`` table of a spec: ``None`` if switched off, else its settings."""
    table = f"{where}: [options.{key}]"
    valid = tuple(f.name for f in dataclasses.fields(kind)) + ("enabled",)
    if isinstance(raw, bool):
        return {} if raw else None
    if not isinstance(raw, Mapping):
        raise SpecError(
            f"{where}: {key} = {_short(raw)} must be true, false{shorthand} or a table with "
            f"keys {', '.join(valid)}"
        )
    _unknown(raw, valid, table, f"{key} keys")
    if not _bool(raw.get("enabled", True), table, "enabled"):
        return None
    for name, value in raw.items():
        _big_int(value, table, name)
    return {k: v for k, v in raw.items() if k != "enabled"}


def _build(kind: type, settings: Mapping, where: str, key: str) -> Any:
    try:
        return kind(**settings)
    except OptionsError as exc:
        raise SpecError(f"{where}: [options.{key}] {str(exc).removeprefix(key + ': ')}") from None


def _cleanup(raw: Any, where: str) -> CleanupSpec | None:
    settings = _table(raw, CleanupSpec, where, "cleanup", "")
    return None if settings is None else _build(CleanupSpec, settings, where, "cleanup")


def _resample(raw: Any, where: str) -> ResampleSpec | None:
    if _is_number(raw):
        raw = {"target_edge": raw}
    settings = _table(raw, ResampleSpec, where, "resample", ", a target edge length")
    if settings is None:
        return None
    if settings.get("target_edge") == "host_curve":
        settings = {**settings, "target_edge": None}
    try:
        return _build(ResampleSpec, settings, where, "resample")
    except SpecError as exc:
        if not str(exc).startswith(f"{where}: [options.resample] target_edge"):
            raise
        raise SpecError(
            f'{exc} or "host_curve" (the mean edge of the host curve, the default)'
        ) from None


def parse_options(
    raw: Mapping, *, where: str, base: Path, folder: Path | None
) -> tuple[JoinOptions, Path | None, CleanupSpec | None, ResampleSpec | None]:
    """Parse an ``[options]`` table.

    Parameters
    ----------
    raw : mapping
        JoinOptions keys plus ``cleanup`` and ``resample``.
    where : str
        Prefix of error messages (the spec file).
    base : pathlib.Path
        Folder that a relative ``stiffness`` path is relative to.
    folder : pathlib.Path or None
        Case folder that the stiffness file must stay inside (``None``: no
        confinement, for files named on the command line).

    Returns
    -------
    options : igljoin.JoinOptions
        The join options (validated once, here).
    stiffness_file : pathlib.Path or None
    cleanup : CleanupSpec or None
    resample : ResampleSpec or None
    """
    if not isinstance(raw, Mapping):
        raise SpecError(f"{where}: [options] must be a table of option = value pairs")
    try:
        raw = new_names(raw, f"{where}: [options]")  # old names: a DeprecationWarning
    except OptionsError as exc:
        raise SpecError(str(exc)) from None
    valid = _join_option_names() + ("cleanup", "resample")
    _unknown(raw, valid, f"{where}: [options]", "options")
    opts = {k: v for k, v in raw.items() if k not in ("cleanup", "resample")}
    stiffness_file = None
    k = opts.get("stiffness")
    if isinstance(k, str):
        if folder is not None:
            stiffness_file = _inside(folder, k, where, "stiffness")
        else:
            stiffness_file = (base / k).resolve()
            if not stiffness_file.is_file():
                raise SpecError(f"{where}: stiffness file {k!r} not found (looked in {base})")
        opts["stiffness"] = _load_stiffness(stiffness_file, where)
    elif isinstance(k, list):
        if not all(map(_is_number, k)):
            raise SpecError(f"{where}: stiffness must be a list of numbers or a file name")
        opts["stiffness"] = np.array(k, dtype=np.float64)
    try:
        options = JoinOptions.make(opts)
    except OptionsError as exc:
        raise SpecError(f"{where}: [options] {exc}") from None
    cleanup = _cleanup(raw["cleanup"], where) if "cleanup" in raw else None
    resample = _resample(raw["resample"], where) if "resample" in raw else None
    return options, stiffness_file, cleanup, resample


def _find_mesh(folder: Path, role: str, where: str) -> Path:
    found = sorted(p for p in folder.glob(f"{role}.*") if p.suffix.lower() in SUPPORTED_SUFFIXES)
    if not found:
        raise SpecError(
            f"{folder}: no {role} mesh; put {role}.ply (or {role} with another suffix of "
            f"{', '.join(SUPPORTED_SUFFIXES)}) in the case folder or name the file with "
            f'{role} = "..." in {SPEC_FILE}'
        )
    if len(found) > 1:
        names = ", ".join(p.name for p in found)
        raise SpecError(
            f"{folder}: several {role} meshes ({names}); name the one to use with "
            f'{role} = "..." in {SPEC_FILE}'
        )
    return _inside(folder, found[0].name, where, role)


#: Largest join.toml read (a spec with an inline stiffness of 20 M values is ~400 MB).
MAX_SPEC_BYTES = 512 << 20


def _read_toml(path: Path) -> dict:
    if tomllib is None:  # pragma: no cover - Python 3.10 without tomli
        raise SpecError(
            f"{path}: reading TOML on Python 3.10 needs the package 'tomli'; pip install tomli"
        )
    try:
        if path.stat().st_size > MAX_SPEC_BYTES:
            raise SpecError(
                f"{path}: {path.stat().st_size:,} bytes is too large for a case spec (at most "
                f"{MAX_SPEC_BYTES:,}); put large arrays such as a stiffness in a .npy file"
            )
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except RecursionError:
        raise SpecError(
            f"{path}: nested too deeply to read (arrays or tables inside each other thousands "
            "of times); a spec needs at most a few levels: fix the file"
        ) from None
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{path}: not valid TOML ({exc}); fix the syntax") from None
    except UnicodeDecodeError as exc:
        raise SpecError(f"{path}: not UTF-8 text ({exc}); save it as UTF-8") from None


def load_case(folder: str | os.PathLike) -> CaseSpec:
    """Read a case folder.

    Parameters
    ----------
    folder : str or os.PathLike
        The case folder: ``host.*``, ``guest.*`` and optionally ``join.toml``
        (without it, each mesh must have a single boundary loop to join).

    Returns
    -------
    CaseSpec

    Raises
    ------
    SpecError
        If the folder or its ``join.toml`` is invalid: unknown keys (the
        message lists the valid ones), wrong value types, a path that leaves
        the folder, missing or ambiguous mesh files, vertex-index curves
        together with resampling.

    Examples
    --------
    >>> spec = load_case("cases/end_to_end-equal")  # doctest: +SKIP
    >>> spec.host_curve, spec.options.smooth  # doctest: +SKIP
    (Curve(indices=None, start=None, end=None, via=None, loop=0, closed=None), True)
    """
    given = Path(folder)
    if not given.is_dir():
        raise SpecError(f"{given}: not a folder; a case is a folder holding host.*, guest.*")
    root = given.resolve()
    spec_path = root / SPEC_FILE
    raw: dict = {}
    spec_file = None
    where = str(given / SPEC_FILE)
    if spec_path.exists() or spec_path.is_symlink():
        spec_file = _inside(root, SPEC_FILE, where, "the spec file")
        raw = _read_toml(spec_file)
    _unknown(raw, _TOP_KEYS, where, "keys")
    description = raw.get("description", "")
    if not isinstance(description, str):
        raise SpecError(f"{where}: description must be a string")
    host = (
        _inside(root, raw["host"], where, "host")
        if "host" in raw
        else _find_mesh(root, "host", where)
    )
    guest = (
        _inside(root, raw["guest"], where, "guest")
        if "guest" in raw
        else _find_mesh(root, "guest", where)
    )
    parsed = parse_options(raw.get("options", {}), where=where, base=root, folder=root)
    return CaseSpec._checked(
        where,
        parsed,
        name=given.name if given.name not in ("", ".", "..") else root.name,
        folder=root,
        host=host,
        guest=guest,
        host_curve=_curve(raw.get("host_curve"), where, "host"),
        guest_curve=_curve(raw.get("guest_curve"), where, "guest"),
        spec_file=spec_file,
        description=description,
    )


def _is_case(folder: Path) -> bool:
    if (folder / SPEC_FILE).exists():
        return True
    return any(
        p.suffix.lower() in SUPPORTED_SUFFIXES
        for role in ("host", "guest")
        for p in folder.glob(f"{role}.*")
    )


def discover_cases(cases_dir: str | os.PathLike) -> list[Path]:
    """The case folders under ``cases_dir``, sorted by name.

    Parameters
    ----------
    cases_dir : str or os.PathLike
        A folder of case folders (each holding ``join.toml``, ``host.*`` or
        ``guest.*``; hidden folders and folders holding none of these are
        skipped), or a single case folder.

    Returns
    -------
    list of pathlib.Path

    Raises
    ------
    SpecError
        If ``cases_dir`` is not a folder or holds no case.
    """
    root = Path(cases_dir)
    if not root.is_dir():
        raise SpecError(f"{root}: not a folder; pass the folder holding one folder per case")
    if _is_case(root):
        return [root]
    cases = sorted(
        p
        for p in root.iterdir()
        if p.is_dir() and not p.name.startswith((".", "_")) and _is_case(p)
    )
    if not cases:
        raise SpecError(
            f"{root}: no case folders found; each case is a folder holding host.*, guest.* and "
            f"{SPEC_FILE} (see docs/pipelines.md)"
        )
    return cases
