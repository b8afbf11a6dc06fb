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

Nothing is lost:

* a case is written into a hidden temporary folder next to its final one
  (``OUT/.NAME.tmp-XXXXXXXX``) and renamed into place with :func:`os.replace`
  only when complete; an existing output is first renamed aside and removed
  after the swap. Stale temporary folders of a killed run are removed by the
  next run;
* inputs are only opened read-only;
* a failing case writes ``error.json`` (type, message, step) and the batch
  goes on;
* ``resume=True`` skips cases whose ``report.json`` lists the same input
  hashes (SHA-256), effective spec, igljoin version and output hashes as now.

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
import re
import secrets
import shutil
import sys
import time
import traceback
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import __version__
from .atomic import atomic_write_text, fsync_dir
from .boundary import Curve, select_curve
from .errors import IgljoinError, OptionsError, SpecError, WeldError, missing_extra
from .io import output_formats, read_mesh
from .join import JoinSolver
from .spec import CaseSpec, discover_cases, file_sha256, load_case

__all__ = [
    "BLAS_ENV",
    "BatchSummary",
    "ROW_FIELDS",
    "case_row",
    "run_batch",
    "SolvedCase",
    "is_current",
    "run_case",
    "solve_case",
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

_STALE_DIR = re.compile(r"^\..+\.(tmp|old)-[0-9a-f]{8}$")
_STALE_FILE = re.compile(r"^\..+\.tmp-[0-9a-f]{8}(\.[A-Za-z0-9]+)?$")


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
    P = mesh.V[sel.indices]
    seg = np.roll(P, -1, axis=0) - P if sel.closed else np.diff(P, axis=0)
    return float(np.linalg.norm(seg, axis=1).mean())


def _has_curve(c: Curve) -> bool:
    return any(getattr(c, k) is not None for k in ("indices", "start", "end", "via", "loop"))


def _clean_meshes(spec: CaseSpec, host, guest, hc: Curve, gc: Curve, options: dict, extra: dict):
    """Cleanup and resampling of a case; returns the meshes, curves and options to join."""
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
                k = options.get("stiffness")
                if k is not None and rep.total:
                    if len(k) != mesh.n_vertices or options.get("stiffness_on") == "face":
                        raise SpecError(
                            f"{spec.name}: a per-face stiffness cannot follow cleanup of the "
                            "guest (it changed faces); give stiffness per vertex or clean the "
                            "guest beforehand with `igljoin clean`"
                        )
                    options = {**options, "stiffness": np.asarray(k)[rep.source]}
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
        warnings.append(f"no snapshot: igljoin.viz is not available ({exc})")
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
    hc, gc, options = spec.host_curve, spec.guest_curve, dict(spec.options)
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
    warnings: list[str] = []
    try:
        paths = result.save(tmp, formats=formats)
    except WeldError as exc:
        warnings.append(f"merged.ply not written: {exc}")
        paths = result.save(tmp, merged=False, formats=formats)
    report = json.loads(paths["report"].read_text(encoding="utf-8"))
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


def _temp_dir(final: Path, kind: str = "tmp") -> Path:
    for _ in range(100):
        tmp = final.with_name(f".{final.name}.{kind}-{secrets.token_hex(4)}")
        try:
            tmp.mkdir()
        except FileExistsError:
            continue
        return tmp
    raise FileExistsError(f"cannot create a temporary folder beside {final}")


def _publish(tmp: Path, final: Path) -> None:
    """Move the complete folder ``tmp`` to ``final``, replacing an old one safely."""
    for f in tmp.iterdir():
        if f.is_file():
            fd = os.open(f, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
    old = None
    if final.exists() or final.is_symlink():
        old = final.with_name(f".{final.name}.old-{secrets.token_hex(4)}")
        os.replace(final, old)
    os.replace(tmp, final)
    fsync_dir(final.parent)
    if old is not None:
        if old.is_dir() and not old.is_symlink():
            shutil.rmtree(old, ignore_errors=True)
        else:
            old.unlink(missing_ok=True)


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
    tmp = _temp_dir(final)
    try:
        atomic_write_text(tmp / ERROR, _json_text(record))
        atomic_write_text(tmp / TIMINGS, _json_text(timings))
        _publish(tmp, final)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def _worker_failure(final: Path, name: str, exc: BaseException) -> dict:
    """Record a case whose worker died: error.json, unless a previous output is there.

    A previous complete output is left untouched (the case did not run, so it
    is not wrong); the summary row reports the failure either way.
    """
    record = _error_record(name, exc, "worker", None)
    record["message"] = (
        f"the worker running this case died or was lost ({exc!r}); rerun the batch with "
        "--resume to retry it"
    )
    if not (final / REPORT).is_file():
        _write_failure(final, record, {"total": None})
    row = dict.fromkeys(ROW_FIELDS)
    row.update(
        name=name,
        status="failed",
        step="worker",
        error_type=record["type"],
        error_message=record["message"],
    )
    return row


def run_case(
    case: str | os.PathLike | CaseSpec,
    out: str | os.PathLike,
    *,
    snapshots: bool = False,
    record_errors: bool = True,
    progress: Any = None,
    formats=None,
) -> dict:
    """Run one case and write its output folder atomically.

    Parameters
    ----------
    case : str, os.PathLike or CaseSpec
        A case folder (read with :func:`igljoin.spec.load_case`) or a spec.
    out : str or os.PathLike
        The case's output folder; its parent is created if missing. It is
        replaced only once the new output is complete.
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
    IgljoinError
        Errors of the case, only with ``record_errors=False``.
    """
    final = Path(out)
    final.parent.mkdir(parents=True, exist_ok=True)
    step = _Step()
    start = time.perf_counter()
    name = case.name if isinstance(case, CaseSpec) else Path(case).name
    inputs = None
    tmp = _temp_dir(final)
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
            shutil.rmtree(tmp, ignore_errors=True)
            tmp.mkdir()
            record = _error_record(name, exc, step.name, inputs)
            atomic_write_text(tmp / ERROR, _json_text(record))
            detail = {
                "total": time.perf_counter() - start,
                "traceback": "".join(traceback.format_exception(exc)),
            }
            atomic_write_text(tmp / TIMINGS, _json_text(detail))
        _publish(tmp, final)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return case_row(final, name=name)


# --------------------------------------------------------------------------- rows and summary


def _load_json(path: Path) -> dict | None:
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except (OSError, ValueError):
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
            warnings="; ".join(report.get("warnings") or []) or None,
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
    doc = {
        "igljoin_version": __version__,
        "cases": len(rows),
        "ok": len(rows) - len(failed),
        "failed": len(failed),
        "failed_cases": failed,
        "rows": rows,
    }
    csv_path = atomic_write_text(out / SUMMARY_CSV, buf.getvalue())
    json_path = atomic_write_text(out / SUMMARY_JSON, _json_text(doc))
    return csv_path, json_path


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
        ``summary_csv`` and ``summary_json``.
    """

    out_dir: Path
    rows: list = field(default_factory=list)
    ran: list = field(default_factory=list)
    skipped: list = field(default_factory=list)
    seconds: float = 0.0
    files: dict = field(default_factory=dict)

    @property
    def n_cases(self) -> int:
        """Number of cases."""
        return len(self.rows)

    @property
    def failed(self) -> list[str]:
        """Names of the cases that failed."""
        return [r["name"] for r in self.rows if r["status"] != "ok"]

    @property
    def ok(self) -> bool:
        """True if every case succeeded."""
        return not self.failed

    def message(self) -> str:
        """One line: ``"3 of 10 cases failed: a, b, c"`` or ``"all 10 cases ok"``."""
        n, bad = self.n_cases, self.failed
        if not bad:
            return f"all {n} cases ok" if n != 1 else "the case is ok"
        shown = ", ".join(bad[:10]) + (", ..." if len(bad) > 10 else "")
        return f"{len(bad)} of {n} cases failed: {shown}"

    def to_json(self) -> dict:
        """Plain-JSON form."""
        return {
            "out_dir": str(self.out_dir),
            "cases": self.n_cases,
            "failed": len(self.failed),
            "failed_cases": self.failed,
            "ran": list(self.ran),
            "skipped": list(self.skipped),
            "seconds": self.seconds,
            "files": {k: str(v) for k, v in self.files.items()},
            "rows": self.rows,
        }


# --------------------------------------------------------------------------- resume


def _json_round_trip(data: Any) -> Any:
    return json.loads(json.dumps(data))


def is_current(case_dir: str | os.PathLike, out: str | os.PathLike, *, snapshots=False) -> bool:
    """Whether ``out`` holds a complete output of ``case_dir`` for its current inputs.

    True when ``report.json`` exists and its input hashes, effective spec and
    igljoin version equal the current ones, every output it lists has the
    recorded SHA-256, and (with ``snapshots``) ``snapshot.png`` exists.
    """
    out = Path(out)
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
    if not isinstance(outputs, dict) or not outputs:
        return False
    for fname, digest in outputs.items():
        f = out / fname
        if not f.is_file() or file_sha256(f) != digest:
            return False
    if snapshots and not (out / SNAPSHOT).is_file():
        return False
    return True


# --------------------------------------------------------------------------- executors


def _init_worker() -> None:
    """Initializer of local worker processes.

    One BLAS/OpenMP thread for libraries loaded from now on (numpy's BLAS is
    already capped by the environment the worker was started with, see
    :func:`_blas_env`), and the worker's standard output (file descriptor 1,
    where polyscope's C++ code prints) goes to standard error, so that the
    batch's own stdout (``--json``) stays clean.
    """
    os.environ.update(BLAS_ENV)
    with contextlib.suppress(Exception):
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)
    with contextlib.suppress(OSError, ValueError):
        sys.stdout.flush()
        os.dup2(2, 1)


def _case_task(payload: dict) -> dict:
    """Executor task: run one case (module-level so that workers can import it)."""
    return run_case(
        payload["case"],
        payload["out"],
        snapshots=payload["snapshots"],
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
    ex = cf.ProcessPoolExecutor(max_workers=n, mp_context=context, initializer=_init_worker)
    try:
        yield ex
    except BaseException:  # interrupted: do not start the cases still waiting
        ex.shutdown(wait=False, cancel_futures=True)
        raise
    ex.shutdown(wait=True)


# --------------------------------------------------------------------------- batch


def _remove_stale(out_dir: Path) -> None:
    """Remove temporary and set-aside folders a killed run left behind."""
    for p in out_dir.iterdir():
        if p.is_symlink():
            continue
        if p.is_dir() and _STALE_DIR.match(p.name):
            shutil.rmtree(p, ignore_errors=True)
        elif p.is_file() and _STALE_FILE.match(p.name):
            p.unlink(missing_ok=True)


@contextlib.contextmanager
def _lock(out_dir: Path) -> Iterator[None]:
    """Refuse to run two batches into one output folder at the same time."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    path = out_dir / LOCK
    with open(path, "a+") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise OSError(
                f"another igljoin batch is writing to {out_dir} (it holds {path}); wait for it "
                "to finish or choose another output folder"
            ) from None
        try:
            yield
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
    out.mkdir(parents=True, exist_ok=True)
    summary = BatchSummary(out_dir=out)
    with _lock(out):
        _remove_stale(out)
        todo = []
        for case in cases:
            if resume and is_current(case, out / case.name, snapshots=snapshots):
                summary.skipped.append(case.name)
            else:
                todo.append(case)
        bar = _progress(len(cases), progress)
        failed = 0
        if bar is not None and summary.skipped:
            bar.update(len(summary.skipped))
        rows: dict[str, dict] = {}
        try:
            if todo:
                with _executor(len(todo), executor, workers, scheduler, dask_local) as ex:
                    futures = {}
                    with _blas_env():
                        for case in todo:
                            payload = {
                                "case": str(case),
                                "out": str(out / case.name),
                                "snapshots": bool(snapshots),
                                "formats": formats,
                            }
                            futures[ex.submit(_case_task, payload)] = case
                    for fut in cf.as_completed(futures):
                        case = futures[fut]
                        try:
                            row = fut.result()
                        except (KeyboardInterrupt, SystemExit):
                            raise
                        except BaseException as exc:  # a worker died or the task was lost
                            row = _worker_failure(out / case.name, case.name, exc)
                        rows[case.name] = row
                        summary.ran.append(case.name)
                        failed += row["status"] != "ok"
                        if bar is not None:
                            bar.set_postfix(
                                done=len(rows) + len(summary.skipped),
                                failed=failed,
                                remaining=len(todo) - len(rows),
                                refresh=False,
                            )
                            bar.update(1)
        finally:
            if bar is not None:
                bar.close()
        for case in cases:
            if case.name not in rows:
                rows[case.name] = case_row(out / case.name, name=case.name)
        summary.rows = sorted(rows.values(), key=lambda r: r["name"])
        csv_path, json_path = write_summary(out, summary.rows)
    summary.files = {"summary_csv": csv_path, "summary_json": json_path}
    summary.ran.sort()
    summary.seconds = time.perf_counter() - start
    return summary
