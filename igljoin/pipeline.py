"""Batch runner: case folders -> executor (local processes | dask) -> outputs + summary.

:func:`run_batch` finds the case folders (see :mod:`igljoin.spec`), runs each
case in a worker and writes, for a case named ``NAME``::

    OUT/NAME/guest.ply       deformed guest (JoinResult.save)
    OUT/NAME/merged.ply      host and guest welded (JoinResult.save)
    OUT/NAME/report.json     the join report + input hashes + effective spec
    OUT/NAME/timings.json    seconds per step (the only per-case file that varies)
    OUT/NAME/snapshot.png    with snapshots=True, when igljoin.viz is available
    OUT/NAME/error.json      instead of the above when the case failed
    OUT/summary.csv, OUT/summary.json   one row per case

Nothing is lost (``docs/pipelines.md``, "Output folders"):

* igljoin never deletes or replaces a file it did not write. A case is
  written into a marked staging folder next to its final one
  (``OUT/.NAME.tmp-XXXXXXXX``) and its files are moved into ``OUT/NAME`` only
  when complete, beside whatever else is there; the folder's manifest
  ``.igljoin-manifest.json`` lists igljoin's files with their SHA-256, and
  only those are ever replaced or removed (:mod:`igljoin.outputs`). Staging
  folders a killed run left are removed by the next run (only marked ones);
* inputs are only opened read-only;
* a failing case writes ``error.json`` (type, message, step) and the batch
  goes on; a case whose outputs cannot all be written (a failed weld, a full
  disk) is failed, never "ok";
* local workers die with the batch process and publish only while their
  batch holds the output folder's lock; a worker that dies is replaced and
  the cases it had not started run on a new pool;
* ``resume=True`` skips a case only if its manifest, report and every output
  still have the hashes recorded at write time, the report's input
  hashes, effective spec and igljoin version are the current ones, and the
  guest and merged meshes exist in every format now requested;
* the summary is kept in memory and written at the end; cases whose outcome
  could not be written anywhere are listed in :attr:`BatchSummary.unrecorded`.

Outputs are deterministic: rerunning, resuming after a kill at any moment or
running on dask gives byte-identical files, except ``*/timings.json`` and the
``time_seconds`` field of ``summary.csv``/``summary.json``, which hold wall
times. (A ``time_limit`` option makes the join itself depend on timing.)
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import csv
import io
import json
import logging
import multiprocessing
import os
import secrets
import shutil
import stat
import sys
import time
import traceback
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from . import __version__
from .atomic import atomic_write_text
from .boundary import Curve, select_curve
from .errors import IgljoinError, OptionsError, OutputError, SpecError, missing_extra
from .io import DEFAULT_OUTPUT_FORMATS, WRITE_SUFFIXES, output_formats, read_mesh
from .join import JoinSolver
from .options import JoinOptions
from .outputs import (
    MANIFEST,
    STAGING_MARK,
    check_folder,
    file_sha256,
    make_staging,
    publish,
    read_manifest,
    remove_stale_staging,
)
from .polyline import mean_segment
from .spec import CaseSpec, discover_cases, load_case

__all__ = [
    "BLAS_ENV",
    "BatchSummary",
    "ROW_FIELDS",
    "case_row",
    "run_batch",
    "SolvedCase",
    "is_current",
    "required_outputs",
    "run_case",
    "solve_case",
    "warning_codes",
    "write_summary",
]


REPORT = "report.json"
TIMINGS = "timings.json"
ERROR = "error.json"
SNAPSHOT = "snapshot.png"
SUMMARY_CSV = "summary.csv"
SUMMARY_JSON = "summary.json"
LOCK = ".igljoin-batch.lock"

#: Environment set in every local worker so each uses one BLAS/OpenMP thread.
BLAS_ENV = {
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "VECLIB_MAXIMUM_THREADS": "1",
    "NUMEXPR_NUM_THREADS": "1",
}

#: Columns of ``summary.csv`` (and keys of each row of ``summary.json``).
ROW_FIELDS = (
    "name",
    "status",
    "step",
    "error_type",
    "error_message",
    "host_vertices",
    "host_faces",
    "guest_vertices",
    "guest_faces",
    "seam",
    "inserted",
    "hard",
    "soft",
    "iterations",
    "converged",
    "seam_gap_max",
    "seam_gap_relative_max",
    "crease_mean",
    "crease_max",
    "area_change_mean",
    "area_change_max",
    "area_ratio_min",
    "area_ratio_max",
    "cleanup_fixes",
    "resampled",
    "warnings",
    "time_seconds",
)

#: Every file name a case folder may receive (checked before a case runs).
CASE_FILES = (
    *(f"{stem}{suffix}" for stem in ("guest", "merged") for suffix in WRITE_SUFFIXES),
    REPORT,
    TIMINGS,
    ERROR,
    SNAPSHOT,
)


def required_outputs(formats=None) -> tuple[str, ...]:
    """Mesh files a successful case must have: guest and merged in every format.

    Parameters
    ----------
    formats : str or iterable of str, optional
        The requested output formats (default
        :data:`igljoin.io.DEFAULT_OUTPUT_FORMATS`, ``("ply", "vtu")``).

    Returns
    -------
    tuple of str
        ``("guest.ply", "guest.vtu", "merged.ply", "merged.vtu")`` by default.
    """
    kinds = output_formats(DEFAULT_OUTPUT_FORMATS if formats is None else formats)
    return tuple(f"{stem}.{fmt}" for stem in ("guest", "merged") for fmt in kinds)


# --------------------------------------------------------------------------- one case


class _Step:
    """The step a case is in, for error reports."""

    def __init__(self) -> None:
        self.name = "spec"


def _json_text(data: Any) -> str:
    """Deterministic JSON: sorted keys, two-space indent, trailing newline."""
    return json.dumps(data, indent=2, sort_keys=True, allow_nan=False) + "\n"


def _mean_curve_edge(mesh, curve: Curve) -> float:
    sel = select_curve(mesh, curve, name="host_curve")
    return mean_segment(mesh.V[sel.indices], sel.closed)


def _has_curve(c: Curve) -> bool:
    return any(getattr(c, k) is not None for k in ("indices", "start", "end", "via", "loop"))


def _clean_meshes(
    spec: CaseSpec, host, guest, hc: Curve, gc: Curve, options: JoinOptions, extra: dict
):
    """Cleanup and resampling of a case; returns the meshes, curves and options to join.

    The options are the case's own unless cleanup renumbered the guest's
    vertices: then a per-vertex stiffness follows them (a new, validated
    :class:`JoinOptions`; the case's options are never changed).
    """
    from .clean import clean, resample

    c = spec.cleanup
    if c is not None:
        extra["cleanup"] = {}
        for role in ("host", "guest"):
            if not getattr(c, role):
                continue
            mesh, curve = (host, hc) if role == "host" else (guest, gc)
            keep = None
            if c.close_holes:
                keep = curve if _has_curve(curve) else Curve(loop=0)
            cleaned, rep = clean(mesh, keep_boundary=keep, **c.clean_kwargs())
            curve = rep.remap_curve(curve, f"{role}_curve")
            extra["cleanup"][role] = rep.to_json()
            if role == "host":
                host, hc = cleaned, curve
            else:
                k = options.stiffness
                if k is not None and rep.total:
                    if len(k) != mesh.n_vertices or options.stiffness_on == "face":
                        raise SpecError(
                            f"{spec.name}: a per-face stiffness cannot follow cleanup of the "
                            "guest (it changed faces); give stiffness per vertex or clean the "
                            "guest beforehand with `igljoin clean`"
                        )
                    options = options.replace(stiffness=k[rep.source])
                guest, gc = cleaned, curve
    r = spec.resample
    if r is not None:
        target = r.target_edge if r.target_edge is not None else _mean_curve_edge(host, hc)
        guest, rep = resample(guest, target, keep=gc, iterations=r.iterations)
        if gc.loop is not None:
            gc = Curve(start=gc.start, end=gc.end, via=gc.via, loop=rep.kept_loop, closed=gc.closed)
        extra["resample"] = rep.to_json()
    return host, guest, hc, gc, options


def _snapshot(result, path: Path, title: str, warnings: list) -> None:
    try:
        from . import viz
    except ImportError as exc:
        warnings.append(
            {
                "code": "no_snapshot",
                "message": f"no snapshot: igljoin.viz is not available ({exc}); install the "
                "viz extra: pip install 'igljoin[viz]'",
                "value": None,
                "threshold": None,
            }
        )
        return
    viz.render(result, path, title=title)


@dataclass
class SolvedCase:
    """A case joined in memory by :func:`solve_case` (nothing written yet).

    Attributes
    ----------
    spec : CaseSpec
    result : JoinResult
    meshes : dict
        Vertex and face counts of the host and guest as read.
    cleanup : dict or None
        :meth:`CleanReport.to_json` per cleaned mesh (``host``, ``guest``).
    resample : dict or None
        :meth:`ResampleReport.to_json` of the guest.
    timings : dict
        Seconds per step (``read``, ``clean``, ``join``).
    """

    spec: CaseSpec
    result: Any
    meshes: dict
    cleanup: dict | None = None
    resample: dict | None = None
    timings: dict = field(default_factory=dict)


def solve_case(spec: CaseSpec, *, step: _Step | None = None, progress: Any = None) -> SolvedCase:
    """Read, clean/resample (if the spec says so) and join one case, in memory.

    Parameters
    ----------
    spec : CaseSpec
    step : optional
        Internal: tracks the step for error reports.
    progress : callable, optional
        Passed to :meth:`igljoin.JoinSolver.solve` (called with an
        :class:`igljoin.SolveProgress` after every iteration).

    Returns
    -------
    SolvedCase

    Raises
    ------
    IgljoinError, OSError
        Whatever reading, cleaning or joining raises.
    """
    step = step or _Step()
    timings: dict[str, Any] = {}
    t = time.perf_counter()
    step.name = "read"
    host = read_mesh(spec.host, name="host")
    guest = read_mesh(spec.guest, name="guest")
    meshes = {
        "host": {"vertices": host.n_vertices, "faces": host.n_faces},
        "guest": {"vertices": guest.n_vertices, "faces": guest.n_faces},
    }
    timings["read"] = time.perf_counter() - t
    t = time.perf_counter()
    step.name = "clean"
    extra: dict[str, Any] = {}
    hc, gc, options = spec.host_curve, spec.guest_curve, spec.options
    if spec.cleanup is not None or spec.resample is not None:
        host, guest, hc, gc, options = _clean_meshes(spec, host, guest, hc, gc, options, extra)
    timings["clean"] = time.perf_counter() - t
    t = time.perf_counter()
    step.name = "join"
    result = JoinSolver(host, guest, hc, gc, options).solve(progress=progress)
    timings["join"] = time.perf_counter() - t
    return SolvedCase(
        spec=spec,
        result=result,
        meshes=meshes,
        cleanup=extra.get("cleanup"),
        resample=extra.get("resample"),
        timings=timings,
    )


def _write_outputs(
    solved: SolvedCase, inputs: dict, tmp: Path, snapshots: bool, step: _Step, formats=None
) -> tuple[dict, dict]:
    """Save a solved case into the folder ``tmp``; return (report, timings)."""
    spec, result = solved.spec, solved.result
    timings = dict(solved.timings)
    t = time.perf_counter()
    step.name = "save"
    # a WeldError fails the case at step "save": merged.ply is required
    paths = result.save(tmp, formats=formats)
    report = json.loads(paths["report"].read_text(encoding="utf-8"))
    # the join's quality warnings, then the batch's own (e.g. no snapshot)
    warnings: list[dict] = list(report.get("warnings") or [])
    timings["solver"] = report.pop("timings", {})
    metrics = report.get("metrics", {})
    if "time_seconds" in metrics:
        timings["solver_total"] = metrics.pop("time_seconds")
    timings["save"] = time.perf_counter() - t
    if snapshots:
        step.name = "snapshot"
        t = time.perf_counter()
        _snapshot(result, tmp / SNAPSHOT, spec.name, warnings)
        timings["snapshot"] = time.perf_counter() - t
    outputs = {p.name: file_sha256(p) for key, p in sorted(paths.items()) if key != "report"}
    report.update(
        {
            "case": spec.name,
            "igljoin_version": __version__,
            "inputs": inputs,
            "spec": _json_round_trip(spec.to_json()),
            "meshes": solved.meshes,
            "outputs": outputs,
            "snapshot": (tmp / SNAPSHOT).exists(),
            "warnings": warnings,
            "cleanup": solved.cleanup,
            "resample": solved.resample,
        }
    )
    atomic_write_text(tmp / REPORT, _json_text(report))
    return report, timings


def _error_record(name: str, exc: BaseException, step: str, inputs: dict | None) -> dict:
    return {
        "case": name,
        "igljoin_version": __version__,
        "type": type(exc).__name__,
        "message": str(exc) or repr(exc),
        "step": step,
        "inputs": inputs,
    }


def _write_failure(final: Path, record: dict, timings: dict) -> None:
    tmp = make_staging(final)
    try:
        atomic_write_text(tmp / ERROR, _json_text(record))
        atomic_write_text(tmp / TIMINGS, _json_text(timings))
        publish(tmp, final, exclusive=True)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def _empty_staging(tmp: Path) -> None:
    """Remove what a failed attempt wrote into a staging folder (its mark stays)."""
    for p in tmp.iterdir():
        if p.name == STAGING_MARK:
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)


def _worker_failure(final: Path, name: str, exc: BaseException, *, step: str = "worker") -> dict:
    """Record a case whose worker died or whose folder could not be written.

    ``error.json`` is written unless a previous complete output is there (the
    case did not run, so that output is not wrong); the summary row reports
    the failure either way. If even ``error.json`` cannot be written (a full
    disk), the row says so and carries ``_unrecorded=True``.
    """
    record = _error_record(name, exc, step, None)
    if step == "worker":
        record["message"] = (
            f"the worker running this case died or was lost ({exc!r}); rerun the batch with "
            "--resume to retry it"
        )
    elif isinstance(exc, OSError):
        record["message"] = _one_line_os(exc)
    unrecorded = False
    if not (final / REPORT).is_file():
        try:
            _write_failure(final, record, {"total": None})
        except (IgljoinError, OSError) as write_exc:
            unrecorded = True
            record["message"] += f" (not recorded in {final}: {_one_line_os_or(write_exc)})"
    row = dict.fromkeys(ROW_FIELDS)
    row.update(
        name=name,
        status="failed",
        step=step,
        error_type=record["type"],
        error_message=record["message"],
    )
    row["_unrecorded"] = unrecorded
    return row


def _one_line_os_or(exc: BaseException) -> str:
    return _one_line_os(exc) if isinstance(exc, OSError) else str(exc)


def run_case(
    case: str | os.PathLike | CaseSpec,
    out: str | os.PathLike,
    *,
    snapshots: bool = False,
    record_errors: bool = True,
    progress: Any = None,
    publish_guard: Any = None,
    formats=None,
) -> dict:
    """Run one case and write its output folder (see ``docs/pipelines.md``).

    Parameters
    ----------
    case : str, os.PathLike or CaseSpec
        A case folder (read with :func:`igljoin.spec.load_case`) or a spec.
    out : str or os.PathLike
        The case's output folder; its parent is created if missing. The
        case's files are written into a staging folder beside it and moved in
        only once complete; files in ``out`` that igljoin did not write are
        never touched, and a file of the same name as one of its outputs that
        igljoin did not write is refused (:class:`~igljoin.errors.OutputError`)
        before the case runs.
    snapshots : bool, optional
        Also render ``snapshot.png`` with :func:`igljoin.viz.render` (skipped
        with a warning in the report if igljoin.viz is not available).
    record_errors : bool, optional
        ``True`` (batch use): an error of the case is written to
        ``error.json`` in ``out`` with the step it happened in (``spec``,
        ``read``, ``clean``, ``join``, ``save`` or ``snapshot``) and the row
        has ``status = "failed"``. ``False``: the error is raised and ``out``
        is left as it was.
    progress : callable, optional
        Called with an :class:`igljoin.SolveProgress` after every iteration
        of the join (see :meth:`igljoin.JoinSolver.solve`).
    publish_guard : callable, optional
        Called just before the outputs are moved into ``out``; if it raises,
        nothing is published (a batch worker checks that its batch still
        holds the output folder's lock).
    formats : str or iterable of str, optional
        Mesh formats of the outputs (default ``("ply", "vtu")``; see
        :meth:`igljoin.JoinResult.save`).

    Returns
    -------
    dict
        The case's summary row (see :data:`ROW_FIELDS`), read back from the
        written files.

    Raises
    ------
    OSError
        If the output folder cannot be written.
    OutputError
        If ``out`` is a file, or holds a file named like one of the case's
        outputs that igljoin did not write.
    IgljoinError
        Errors of the case, only with ``record_errors=False``.
    """
    final = Path(out)
    check_folder(final, CASE_FILES, what="output folder")
    final.parent.mkdir(parents=True, exist_ok=True)
    step = _Step()
    start = time.perf_counter()
    name = case.name if isinstance(case, CaseSpec) else Path(case).name
    inputs = None
    tmp = make_staging(final)
    try:
        try:
            spec = case if isinstance(case, CaseSpec) else load_case(case)
            name = spec.name
            step.name = "read"
            inputs = spec.input_hashes()
            solved = solve_case(spec, step=step, progress=progress)
            _, timings = _write_outputs(solved, inputs, tmp, snapshots, step, formats)
            timings["total"] = time.perf_counter() - start
            atomic_write_text(tmp / TIMINGS, _json_text(timings))
        except Exception as exc:  # any failure of the case is recorded, not raised
            if not record_errors:
                raise
            _empty_staging(tmp)
            record = _error_record(name, exc, step.name, inputs)
            atomic_write_text(tmp / ERROR, _json_text(record))
            detail = {
                "total": time.perf_counter() - start,
                "traceback": "".join(traceback.format_exception(exc)),
            }
            atomic_write_text(tmp / TIMINGS, _json_text(detail))
        if publish_guard is not None:
            publish_guard()
        publish(tmp, final, exclusive=True)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return case_row(final, name=name)


# --------------------------------------------------------------------------- rows and summary


#: Largest JSON file igljoin reads back from an output folder (a report is ~10 kB).
_MAX_JSON_BYTES = 64 << 20


def _load_json(path: Path) -> dict | None:
    """A JSON object read from ``path``, or None if it is not a sound igljoin file.

    Only regular files are opened (a FIFO or device would block), at most
    :data:`_MAX_JSON_BYTES`; deep nesting (``RecursionError``) counts as
    unreadable.
    """
    try:
        st = os.stat(path)
        if not stat.S_ISREG(st.st_mode) or st.st_size > _MAX_JSON_BYTES:
            return None
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except (OSError, ValueError, RecursionError):
        return None
    return data if isinstance(data, dict) else None


def _get(d: dict | None, *keys: str) -> Any:
    for k in keys:
        if not isinstance(d, dict):
            return None
        d = d.get(k)
    return d


def _cleanup_total(cleanup: dict | None) -> int | None:
    if not cleanup:
        return None
    return sum(int(_get(rep, "total") or 0) for rep in cleanup.values())


def warning_codes(report: dict | None) -> list[str]:
    """The warning codes of a case's ``report.json`` (see ``docs/warnings.md``), in order.

    Each entry of ``report["warnings"]`` is ``{"code", "message", "value",
    "threshold"}``; a plain string (reports of older versions) counts as its
    own code.
    """
    found = _get(report, "warnings") if isinstance(report, dict) else None
    if not isinstance(found, list):
        return []
    codes = []
    for w in found:
        code = w.get("code") if isinstance(w, dict) else w
        if isinstance(code, str) and code:
            codes.append(code)
    return codes


def case_row(folder: str | os.PathLike, *, name: str | None = None) -> dict:
    """The summary row of a case output folder (read from its files).

    Parameters
    ----------
    folder : str or os.PathLike
        ``OUT/NAME``.
    name : str, optional
        Case name (defaults to the folder name).

    Returns
    -------
    dict
        Keys :data:`ROW_FIELDS`; ``status`` is ``"ok"``, ``"failed"`` or
        ``"missing"`` (no output).
    """
    folder = Path(folder)
    row: dict[str, Any] = dict.fromkeys(ROW_FIELDS)
    row["name"] = name or folder.name
    timings = _load_json(folder / TIMINGS)
    row["time_seconds"] = _get(timings, "total")
    report = _load_json(folder / REPORT)
    error = _load_json(folder / ERROR)
    if report is not None:
        row["status"] = "ok"
        counts = report.get("counts", {})
        m = report.get("metrics", {})
        row.update(
            host_vertices=_get(report, "meshes", "host", "vertices"),
            host_faces=_get(report, "meshes", "host", "faces"),
            guest_vertices=counts.get("points"),
            guest_faces=counts.get("faces"),
            seam=counts.get("seam"),
            inserted=counts.get("inserted"),
            hard=counts.get("hard"),
            soft=counts.get("soft"),
            iterations=report.get("iterations"),
            converged=report.get("converged"),
            seam_gap_max=_get(m, "seam_gap", "max"),
            seam_gap_relative_max=_get(m, "seam_gap", "relative_max"),
            crease_mean=_get(m, "crease_deg", "mean"),
            crease_max=_get(m, "crease_deg", "max"),
            area_change_mean=_get(m, "area_change", "mean"),
            area_change_max=_get(m, "area_change", "max"),
            area_ratio_min=_get(m, "area_ratio", "min"),
            area_ratio_max=_get(m, "area_ratio", "max"),
            cleanup_fixes=_cleanup_total(report.get("cleanup")),
            resampled=report.get("resample") is not None,
            warnings=";".join(warning_codes(report)) or None,
        )
    elif error is not None:
        row.update(
            status="failed",
            step=error.get("step"),
            error_type=error.get("type"),
            error_message=error.get("message"),
        )
    else:
        row["status"] = "missing"
    return row


def write_summary(out_dir: str | os.PathLike, rows: list[dict]) -> tuple[Path, Path]:
    """Write ``summary.csv`` and ``summary.json`` atomically (rows sorted by name).

    Both are staged and moved into ``out_dir`` together and recorded in its
    manifest; a foreign file of either name is refused (:class:`OutputError`).

    Returns
    -------
    (pathlib.Path, pathlib.Path)
        The CSV and JSON files.
    """
    out = Path(out_dir)
    rows = sorted(rows, key=lambda r: r["name"])
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(ROW_FIELDS), lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in ROW_FIELDS})
    failed = [r["name"] for r in rows if r["status"] != "ok"]
    warned = [r["name"] for r in rows if r["status"] == "ok" and r.get("warnings")]
    doc = {
        "igljoin_version": __version__,
        "cases": len(rows),
        "ok": len(rows) - len(failed),
        "failed": len(failed),
        "failed_cases": failed,
        "warned": len(warned),
        "warned_cases": warned,
        "rows": rows,
    }
    tmp = make_staging(out)
    try:
        atomic_write_text(tmp / SUMMARY_CSV, buf.getvalue())
        atomic_write_text(tmp / SUMMARY_JSON, _json_text(doc))
        publish(tmp, out, exclusive=False)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return out / SUMMARY_CSV, out / SUMMARY_JSON


@dataclass
class BatchSummary:
    """What :func:`run_batch` did.

    Attributes
    ----------
    out_dir : pathlib.Path
    rows : list of dict
        One row per case (sorted by name); see :data:`ROW_FIELDS`.
    ran : list of str
        Cases run in this call.
    skipped : list of str
        Cases skipped by ``resume`` (their outputs were complete and current).
    seconds : float
        Wall time of the batch.
    files : dict of str to pathlib.Path
        ``summary_csv`` and ``summary_json`` (empty if they could not be
        written, see ``summary_error``).
    unrecorded : list of str
        Cases whose outcome could not be written into their folder (e.g. a
        full disk): their row in :attr:`rows` is the only record.
    summary_error : str or None
        Why ``summary.csv``/``summary.json`` could not be written, if so.
    """

    out_dir: Path
    rows: list = field(default_factory=list)
    ran: list = field(default_factory=list)
    skipped: list = field(default_factory=list)
    seconds: float = 0.0
    files: dict = field(default_factory=dict)
    unrecorded: list = field(default_factory=list)
    summary_error: str | None = None

    @property
    def n_cases(self) -> int:
        """Number of cases."""
        return len(self.rows)

    @property
    def failed(self) -> list[str]:
        """Names of the cases that failed."""
        return [r["name"] for r in self.rows if r["status"] != "ok"]

    @property
    def warned(self) -> list[str]:
        """Names of the cases that succeeded with quality warnings (see ``docs/warnings.md``)."""
        return [r["name"] for r in self.rows if r["status"] == "ok" and r.get("warnings")]

    @property
    def ok(self) -> bool:
        """True if every case succeeded (with or without warnings)."""
        return not self.failed

    def message(self) -> str:
        """One line: ``"3 of 10 cases failed: a, b, c"`` or ``"all 10 cases ok"``.

        Cases with quality warnings are named after it: ``"all 10 cases ok;
        2 with warnings: d, e"``.
        """
        n, bad, warned = self.n_cases, self.failed, self.warned
        if not bad:
            text = f"all {n} cases ok" if n != 1 else "the case is ok"
        else:
            text = f"{len(bad)} of {n} cases failed: {_names(bad)}"
        if warned:
            text += f"; {len(warned)} with warnings: {_names(warned)}"
        return text

    def to_json(self) -> dict:
        """Plain-JSON form."""
        return {
            "out_dir": str(self.out_dir),
            "cases": self.n_cases,
            "failed": len(self.failed),
            "failed_cases": self.failed,
            "warned": len(self.warned),
            "warned_cases": self.warned,
            "ran": list(self.ran),
            "skipped": list(self.skipped),
            "seconds": self.seconds,
            "files": {k: str(v) for k, v in self.files.items()},
            "unrecorded": list(self.unrecorded),
            "summary_error": self.summary_error,
            "rows": self.rows,
        }


# --------------------------------------------------------------------------- resume


def _names(names: list[str], shown: int = 10) -> str:
    return ", ".join(names[:shown]) + (", ..." if len(names) > shown else "")


def _json_round_trip(data: Any) -> Any:
    return json.loads(json.dumps(data))


def is_current(
    case_dir: str | os.PathLike, out: str | os.PathLike, *, snapshots=False, formats=None
) -> bool:
    """Whether ``out`` holds a complete output of ``case_dir`` for its current inputs.

    True when the folder's manifest (written when the outputs were published)
    lists ``report.json`` and every file still has the SHA-256 recorded
    there, so that the report is the one igljoin wrote; the report's input
    hashes, effective spec and igljoin version equal the current ones; the
    outputs it lists include the guest and merged mesh in every requested
    format (:func:`required_outputs` of ``formats``: a format asked for now
    but not written then means "redo"; files of formats no longer asked for
    are left alone) and match the manifest; and (with ``snapshots``)
    ``snapshot.png`` is among them. Anything else, including a report that
    cannot be read, means "redo".
    """
    out = Path(out)
    manifest = read_manifest(out)
    if REPORT not in manifest or ERROR in manifest:
        return False
    for fname, digest in manifest.items():
        f = out / fname
        try:
            if digest is None or f.is_symlink() or not f.is_file() or file_sha256(f) != digest:
                return False
        except OSError:
            return False
    report = _load_json(out / REPORT)
    if report is None or report.get("igljoin_version") != __version__:
        return False
    try:
        spec = load_case(case_dir)
        if report.get("inputs") != spec.input_hashes():
            return False
        if report.get("spec") != _json_round_trip(spec.to_json()):
            return False
    except (IgljoinError, OSError):
        return False
    outputs = report.get("outputs")
    if not isinstance(outputs, dict) or not set(required_outputs(formats)) <= set(outputs):
        return False
    if any(manifest.get(fname) != digest for fname, digest in outputs.items()):
        return False
    if snapshots and SNAPSHOT not in outputs:
        return False
    return True


# --------------------------------------------------------------------------- executors


def _die_with_parent(parent_pid: int) -> None:
    """End this worker process as soon as the process that started it is gone.

    Two mechanisms, so that a SIGKILL of the batch never leaves workers
    running (and writing): on Linux the kernel sends SIGKILL at the parent's
    death (``prctl(PR_SET_PDEATHSIG)``); everywhere, a daemon thread polls
    the parent id every 0.1 s and calls :func:`os._exit` when it changes.
    """
    if sys.platform.startswith("linux"):
        with contextlib.suppress(Exception):
            import ctypes
            import signal

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # PR_SET_PDEATHSIG = 1
    if os.getppid() != parent_pid:  # the parent died before the line above ran
        os._exit(1)

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(0.1)
        os._exit(1)

    import threading

    threading.Thread(target=watch, name="igljoin-parent-watch", daemon=True).start()


def _init_worker(parent_pid: int | None = None) -> None:
    """Initializer of local worker processes.

    The worker ends when the batch process does (:func:`_die_with_parent`).

    One BLAS/OpenMP thread for libraries loaded from now on (numpy's BLAS is
    already capped by the environment the worker was started with, see
    :func:`_blas_env`), and the worker's standard output (file descriptor 1,
    where polyscope's C++ code prints) goes to standard error, so that the
    batch's own stdout (``--json``) stays clean.
    """
    if parent_pid is not None:
        _die_with_parent(parent_pid)
    os.environ.update(BLAS_ENV)
    with contextlib.suppress(Exception):
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)
    with contextlib.suppress(OSError, ValueError):
        sys.stdout.flush()
        os.dup2(2, 1)


def _lock_guard(lock_path: str | None, token: str | None):
    """A ``publish_guard`` that refuses to publish unless the batch still holds its lock.

    The batch writes a random token into its lock file; a worker whose batch
    was killed (and whose output folder may now be written by another batch)
    finds a different token or no lock file and publishes nothing.
    """
    if lock_path is None:
        return None

    def guard() -> None:
        try:
            with open(lock_path, encoding="utf-8") as fh:
                held = fh.read(256).strip()
        except OSError:
            held = None
        if held != token:
            raise OutputError(
                f"the batch that started this case no longer holds {lock_path}; "
                "its outputs were not published"
            )

    return guard


def _case_task(payload: dict) -> dict:
    """Executor task: run one case (module-level so that workers can import it)."""
    return run_case(
        payload["case"],
        payload["out"],
        snapshots=payload["snapshots"],
        publish_guard=_lock_guard(payload.get("lock"), payload.get("token")),
        formats=payload.get("formats"),
    )


@contextlib.contextmanager
def _blas_env() -> Iterator[None]:
    """Set :data:`BLAS_ENV` while worker processes are started (they inherit it).

    numpy loads its BLAS when imported, which happens in a spawned worker
    before any initializer runs; so the variables must be in the environment
    the worker starts with.
    """
    saved = {k: os.environ.get(k) for k in BLAS_ENV}
    os.environ.update(BLAS_ENV)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


class _InlineExecutor(cf.Executor):
    """Runs each task at submit time in this process (``workers=0``)."""

    def submit(self, fn, /, *args, **kwargs):
        future: cf.Future = cf.Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as exc:
            future.set_exception(exc)
        return future


@contextlib.contextmanager
def _executor(
    n_tasks: int,
    executor: cf.Executor | None,
    workers: int | None,
    scheduler: str | None,
    dask_local: int | None,
) -> Iterator[cf.Executor]:
    chosen = [
        k
        for k, v in (("executor", executor), ("scheduler", scheduler), ("dask_local", dask_local))
        if v is not None
    ]
    if len(chosen) > 1:
        raise OptionsError(
            f"run_batch: {' and '.join(chosen)} were both given; choose one way to run the cases"
        )
    if workers is not None and chosen:
        raise OptionsError(
            f"run_batch: workers applies to local processes only, not with {chosen[0]}"
        )
    if executor is not None:
        yield executor
        return
    if scheduler is not None or dask_local is not None:
        try:
            import distributed
        except ImportError:
            raise missing_extra("distributed", "dask", "running a batch on dask") from None
        if dask_local is not None:
            if isinstance(dask_local, bool) or not isinstance(dask_local, int) or dask_local < 1:
                raise OptionsError(f"run_batch: dask_local={dask_local!r} must be an integer >= 1")
            cluster = distributed.LocalCluster(
                n_workers=dask_local,
                threads_per_worker=1,
                processes=True,
                host="127.0.0.1",
                dashboard_address=None,
                silence_logs=logging.ERROR,
            )
            with cluster, distributed.Client(cluster) as client:
                yield client.get_executor(pure=False)
            return
        with distributed.Client(scheduler, timeout="20s") as client:
            yield client.get_executor(pure=False)
        return
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)):
        raise OptionsError(f"run_batch: workers={workers!r} must be an integer >= 0")
    if workers is not None and workers < 0:
        raise OptionsError(f"run_batch: workers={workers!r} must be an integer >= 0")
    if workers == 0:
        yield _InlineExecutor()
        return
    n = workers or max(1, min(n_tasks, os.cpu_count() or 1))
    # spawn, not fork (BLAS pools, EGL contexts) nor forkserver (its server process
    # is shared by the whole program and keeps the environment it started with)
    context = multiprocessing.get_context("spawn")
    ex = cf.ProcessPoolExecutor(
        max_workers=n, mp_context=context, initializer=_init_worker, initargs=(os.getpid(),)
    )
    try:
        yield ex
    except BaseException:  # interrupted: do not start the cases still waiting
        ex.shutdown(wait=False, cancel_futures=True)
        raise
    ex.shutdown(wait=True)


# --------------------------------------------------------------------------- batch


@contextlib.contextmanager
def _lock(out_dir: Path) -> Iterator[tuple[Path, str]]:
    """Refuse to run two batches into one output folder at the same time.

    Yields the lock file and a random token written into it: workers publish
    only while the file still holds that token (:func:`_lock_guard`).
    """
    token = secrets.token_hex(16)
    path = out_dir / LOCK
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield path, token
        return
    if path.is_symlink() or (path.exists() and not path.is_file()):
        raise OutputError(
            f"{path} is not a regular file; it is igljoin's batch lock: remove it and run again"
        )
    with open(path, "a+") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise OSError(
                f"another igljoin batch is writing to {out_dir} (it holds {path}); wait for it "
                "to finish or choose another output folder"
            ) from None
        try:
            fh.seek(0)
            fh.truncate()
            fh.write(token + "\n")
            fh.flush()
            yield path, token
        finally:
            path.unlink(missing_ok=True)  # still locked by us: nobody else can be using it


def _progress(total: int, enabled: bool):
    if not enabled or not sys.stderr.isatty() or total == 0:
        return None
    try:
        from tqdm import tqdm
    except ImportError:
        return None
    return tqdm(total=total, file=sys.stderr, unit="case", desc="igljoin batch", leave=True)


def run_batch(
    cases_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    executor: cf.Executor | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    dask_local: int | None = None,
    resume: bool = False,
    progress: bool = True,
    snapshots: bool = False,
    formats=None,
) -> BatchSummary:
    """Run every case folder under ``cases_dir`` and write outputs and a summary.

    Parameters
    ----------
    cases_dir : str or os.PathLike
        Folder of case folders (or one case folder); see
        :func:`igljoin.spec.discover_cases` and ``docs/pipelines.md``.
    out_dir : str or os.PathLike
        Output folder (created if missing): one sub-folder per case plus
        ``summary.csv`` and ``summary.json``.
    executor : concurrent.futures.Executor, optional
        Run the cases on this executor (it is not shut down). Its workers
        must be able to import igljoin and see both folders.
    workers : int, optional
        Number of local worker processes (default: one per CPU, at most one
        per case); ``0`` runs the cases one by one in this process.
    scheduler : str, optional
        Address of a dask scheduler (``"tcp://host:8786"``); cases run on its
        workers through ``distributed.Client(address).get_executor()``. The
        workers must share the file system paths.
    dask_local : int, optional
        Start a ``distributed.LocalCluster`` with this many single-threaded
        worker processes on the loopback interface for the batch.
    resume : bool, optional
        Skip cases whose outputs are complete and whose inputs, spec and
        igljoin version are unchanged (compared by SHA-256 in ``report.json``).
        Failed cases are always rerun.
    progress : bool, optional
        Show a progress bar (tqdm, on stderr; only when stderr is a terminal).
    snapshots : bool, optional
        Also render ``snapshot.png`` per case with :func:`igljoin.viz.render`.
    formats : str or iterable of str, optional
        Mesh formats of each case's outputs (default ``("ply", "vtu")``; see
        :meth:`igljoin.JoinResult.save`).

    Returns
    -------
    BatchSummary

    Raises
    ------
    SpecError
        If ``cases_dir`` holds no case folder.
    OptionsError
        If the executor arguments conflict or are out of range.
    OSError
        If the output folder cannot be written or another batch is writing it.

    Notes
    -----
    Local workers are started with the ``spawn`` method, never ``fork``, with ``OMP_NUM_THREADS``,
    ``OPENBLAS_NUM_THREADS`` and ``MKL_NUM_THREADS`` set to 1 in their
    environment. dask's ``LocalCluster`` sets the same variables for its
    workers (``distributed.nanny.pre-spawn-environ``); on a remote cluster
    configure them there.

    Examples
    --------
    >>> summary = run_batch("cases", "out", workers=2)  # doctest: +SKIP
    >>> summary.message()  # doctest: +SKIP
    'all 10 cases ok'
    """
    start = time.perf_counter()
    formats = None if formats is None else output_formats(formats)
    cases = discover_cases(cases_dir)
    names = [c.name for c in cases]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise SpecError(f"{cases_dir}: case names repeat ({', '.join(dupes)})")
    out = Path(out_dir)
    check_folder(out, (SUMMARY_CSV, SUMMARY_JSON), what="output folder")
    out.mkdir(parents=True, exist_ok=True)
    summary = BatchSummary(out_dir=out)
    local_pool = executor is None and scheduler is None and dask_local is None and workers != 0
    with _lock(out) as (lock_path, token):
        _remove_stale(out)
        todo = []
        for case in cases:
            if resume and is_current(case, out / case.name, snapshots=snapshots, formats=formats):
                summary.skipped.append(case.name)
            else:
                todo.append(case)
        bar = _progress(len(cases), progress)
        if bar is not None and summary.skipped:
            bar.update(len(summary.skipped))
        rows: dict[str, dict] = {}
        guard = {"lock": str(lock_path), "token": token}
        try:
            if todo:
                run = _Run(out, snapshots, guard, rows, summary, bar, len(todo), formats)
                if local_pool:
                    run.local(todo, workers)
                else:
                    with _executor(len(todo), executor, workers, scheduler, dask_local) as ex:
                        run.round(ex, todo, isolated=True)
        finally:
            if bar is not None:
                bar.close()
        _remove_stale(out)  # what a dead worker left (its staging folder)
        for case in cases:
            if case.name not in rows:
                rows[case.name] = case_row(out / case.name, name=case.name)
        summary.rows = sorted(rows.values(), key=lambda r: r["name"])
        try:
            csv_path, json_path = write_summary(out, summary.rows)
            summary.files = {"summary_csv": csv_path, "summary_json": json_path}
        except OSError as exc:
            summary.summary_error = _one_line_os(exc)
    summary.ran.sort()
    summary.unrecorded.sort()
    summary.seconds = time.perf_counter() - start
    return summary


class _Run:
    """The cases of one batch on executors: results, retries, rows, progress."""

    def __init__(self, out, snapshots, guard, rows, summary, bar, total, formats=None):
        self.out, self.snapshots, self.guard = out, snapshots, guard
        self.formats = formats
        self.rows, self.summary, self.bar, self.total = rows, summary, bar, total
        self.failed = 0

    def local(self, todo: list, workers: int | None) -> None:
        """Run on local process pools; a dead worker's pool is replaced.

        When a worker dies (killed, out of memory), the pool breaks and every
        case still in it fails with ``BrokenProcessPool``. The cases that had
        not started (no staging folder of theirs exists) are queued again on a
        new pool; the ones that had started are retried one at a time, each
        alone on its own pool, so that the case whose worker dies again is
        known and recorded as failed with the reason, and the others succeed.
        """
        queue, suspects = list(todo), []
        while queue or suspects:
            if queue:
                batch, queue, isolated = queue, [], False
            else:
                batch, isolated = [suspects.pop(0)], True
            with _executor(len(batch), None, workers, None, None) as ex:
                broken = self.round(ex, batch, isolated=isolated)
            for case in broken:
                started = _staging_of(self.out, case.name)
                for p in started:
                    shutil.rmtree(p, ignore_errors=True)
                (suspects if started else queue).append(case)

    def round(self, ex, batch: list, *, isolated: bool) -> list:
        """Submit ``batch`` to ``ex`` and record the results; return the cases to retry."""
        futures = {}
        with _blas_env():
            for case in batch:
                payload = {
                    "case": str(case),
                    "out": str(self.out / case.name),
                    "snapshots": bool(self.snapshots),
                    "formats": self.formats,
                    **self.guard,
                }
                futures[ex.submit(_case_task, payload)] = case
        retry = []
        for fut in cf.as_completed(futures):
            case = futures[fut]
            try:
                row = fut.result()
            except (KeyboardInterrupt, SystemExit):
                raise
            except cf.BrokenExecutor as exc:  # BrokenProcessPool: a worker died
                if not isolated:
                    retry.append(case)
                    continue
                row = self.lost(case, exc)
            except (IgljoinError, OSError) as exc:  # the case's folder could not be written
                row = self.lost(case, exc, step="output")
            except BaseException as exc:  # a worker died or the task was lost
                row = self.lost(case, exc)
            self.record(case, row)
        return retry

    def lost(self, case, exc: BaseException, step: str = "worker") -> dict:
        row = _worker_failure(self.out / case.name, case.name, exc, step=step)
        if row.pop("_unrecorded", False):
            self.summary.unrecorded.append(case.name)
        return row

    def record(self, case, row: dict) -> None:
        self.rows[case.name] = row
        self.summary.ran.append(case.name)
        self.failed += row["status"] != "ok"
        if self.bar is not None:
            self.bar.set_postfix(
                done=len(self.rows) + len(self.summary.skipped),
                failed=self.failed,
                remaining=self.total - len(self.rows),
                refresh=False,
            )
            self.bar.update(1)


def _staging_of(out: Path, name: str) -> list[Path]:
    """Marked staging folders of case ``name`` in ``out`` (left when its worker died)."""
    prefix = f".{name}.tmp-"
    return [
        p
        for p in out.iterdir()
        if p.name.startswith(prefix) and p.is_dir() and (p / STAGING_MARK).is_file()
    ]


def _remove_stale(out: Path) -> None:
    """Remove staging folders a killed run or a dead worker left in ``out`` and its cases."""
    remove_stale_staging(out)
    for p in out.iterdir():
        if p.is_dir() and not p.is_symlink() and (p / MANIFEST).is_file():
            remove_stale_staging(p)


def _one_line_os(exc: OSError) -> str:
    text = exc.strerror or str(exc)
    if exc.filename is not None and str(exc.filename) not in text:
        text += f": {exc.filename}"
    return text
