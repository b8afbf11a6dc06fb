"""The ``igljoin`` command line: thin, it parses arguments and calls the library.

Subcommands: ``join``, ``batch``, ``clean``, ``info``, ``demo``, ``render``
and ``inspect`` (``igljoin SUBCOMMAND --help`` for each).

Exit codes: 0 when everything succeeded; 1 when a join, a file or some cases
failed (``batch`` prints "3 of 10 cases failed"); 2 for usage errors. Errors
from igljoin and the file system print one line to stderr, never a
traceback. ``--json`` prints machine-readable output on stdout.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import textwrap
from pathlib import Path
from typing import Any

from . import __version__
from .errors import IgljoinError, MissingExtraError, SpecError

__all__ = ["build_parser", "main"]

PROG = "igljoin"


# --------------------------------------------------------------------------- argument types


def _vertex_arg(text: str) -> int | list[float]:
    """A vertex index (``12``) or a point (``1.5,-2,0.25``)."""
    parts = [p.strip() for p in text.split(",")]
    try:
        if len(parts) == 1:
            value = int(parts[0])
            if value < 0:
                raise ValueError
            return value
        if len(parts) == 3:
            point = [float(p) for p in parts]
            if all(math.isfinite(v) for v in point):
                return point
    except ValueError:
        pass
    raise argparse.ArgumentTypeError(
        f"{text!r} is neither a vertex index (an integer >= 0) nor a point x,y,z"
    )


def _indices_arg(text: str) -> list[int]:
    try:
        values = [int(p) for p in text.split(",") if p.strip()]
    except ValueError:
        values = []
    if not values or min(values) < 0:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a comma-separated list of vertex indices (e.g. 0,1,2,3)"
        )
    return values


def _point_arg(text: str) -> list[float]:
    value = _vertex_arg(text)
    if not isinstance(value, list):
        raise argparse.ArgumentTypeError(f"{text!r} is not a point x,y,z")
    return value


def _number_arg(text: str, kind: type, accept: Any, what: str) -> Any:
    """``kind(text)`` if it converts and ``accept`` holds for it; else the message ``what``."""
    try:
        value = kind(text)
    except ValueError:
        value = None
    if value is None or not accept(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not {what}")
    return value


def _nonnegative_int(text: str) -> int:
    return _number_arg(text, int, lambda v: v >= 0, "an integer >= 0")


def _positive_int(text: str) -> int:
    return _number_arg(text, int, lambda v: v >= 1, "an integer >= 1")


def _positive_float(text: str) -> float:
    return _number_arg(text, float, lambda v: math.isfinite(v) and v > 0, "a positive number")


def _option_value(text: str) -> Any:
    """Parse ``--option`` values as TOML (numbers, booleans, arrays); else a plain string."""
    import tomllib

    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def _option_arg(text: str) -> tuple[list[str], Any]:
    key, sep, value = text.partition("=")
    key = key.strip()
    if not sep or not key:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not key=value (e.g. smooth_weight=5 or cleanup.close_holes=true)"
        )
    return key.split("."), _option_value(value.strip())


# --------------------------------------------------------------------------- parser


class _Formatter(argparse.HelpFormatter):
    """Wraps prose paragraphs; keeps example blocks (indented lines) as written."""

    def __init__(self, prog: str) -> None:
        super().__init__(prog, max_help_position=34, width=100)

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        paragraphs = []
        for para in text.split("\n\n"):
            lines = para.splitlines()
            if any(line.startswith("  ") for line in lines):
                paragraphs.append("\n".join(indent + line for line in lines))
            else:
                paragraphs.append(
                    textwrap.fill(
                        " ".join(lines), width, initial_indent=indent, subsequent_indent=indent
                    )
                )
        return "\n\n".join(paragraphs)


def _add_curve_flags(p: argparse.ArgumentParser) -> None:
    for role in ("host", "guest"):
        g = p.add_argument_group(
            f"{role} curve",
            f"Which boundary of the {role} to join. Default: its only boundary loop. V is a "
            "vertex index or a point x,y,z snapped to the nearest boundary vertex.",
        )
        g.add_argument(
            f"--{role}-loop",
            type=_nonnegative_int,
            metavar="K",
            help="boundary loop index (0 = the loop with most vertices)",
        )
        g.add_argument(
            f"--{role}-start",
            type=_vertex_arg,
            metavar="V",
            help="start vertex (alone: start of a closed curve)",
        )
        g.add_argument(
            f"--{role}-end", type=_vertex_arg, metavar="V", help="end vertex of an open curve"
        )
        g.add_argument(
            f"--{role}-via",
            type=_vertex_arg,
            metavar="V",
            help="a vertex on the wanted side between start and end",
        )
        g.add_argument(
            f"--{role}-indices",
            type=_indices_arg,
            metavar="I,J,...",
            help="the curve's boundary vertices in order",
        )


def _formats(text: str) -> tuple[str, ...]:
    """``--formats`` value: comma-separated output formats (checked by igljoin.io)."""
    from .errors import OptionsError
    from .io import output_formats

    try:
        return output_formats(text)
    except OptionsError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


_FORMATS_HELP = "output mesh formats, comma-separated (default: ply,vtu; also vtk, obj, off, stl)"


def _add_option_flags(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("join options")
    g.add_argument(
        "--no-smooth",
        action="store_true",
        help="leave out the smooth-join term (the paper's 'without' variant)",
    )
    g.add_argument(
        "--option",
        "-O",
        action="append",
        type=_option_arg,
        default=[],
        metavar="KEY=VALUE",
        help="any igljoin.JoinOptions key (repeatable), e.g. smooth_weight=5, "
        "stiffness=k.npy, cleanup.close_holes=true",
    )
    g.add_argument(
        "--cleanup", action="store_true", help="repair host and guest with pymeshlab before joining"
    )
    g.add_argument(
        "--resample",
        action="store_true",
        help="remesh the guest to the host curve's mean edge length (or --target-edge), "
        "keeping its boundary; the guest curve must then be given by loop or points",
    )
    g.add_argument(
        "--target-edge",
        type=_positive_float,
        metavar="EDGE",
        help="edge length for --resample",
    )


_EPILOG = """\
examples:
  igljoin info host.ply
  igljoin join host.ply guest.obj -o out/case1 --host-loop 0 --guest-start 1.5,0,2
  igljoin batch cases/ -o out/ --workers 4 --resume
  igljoin batch cases/ -o out/ --dask-local 2
  igljoin clean scan.ply -o scan-clean.ply --close-holes --keep-loop 0
  igljoin demo --out out/demo

Case folders, join.toml and outputs: docs/pipelines.md.
"""


def build_parser() -> argparse.ArgumentParser:
    """The ``igljoin`` argument parser (one sub-parser per subcommand)."""
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Deform a flexible guest mesh so that one of its boundary curves joins a "
        "rigid host's boundary curve exactly and smoothly.",
        epilog=_EPILOG,
        formatter_class=_Formatter,
    )
    parser.add_argument("--version", action="version", version=f"igljoin {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", title="commands")

    p = sub.add_parser(
        "join",
        help="join one guest mesh file to one host mesh file",
        description="Join GUEST to HOST and write guest.ply, merged.ply, guest.vtu, merged.vtu, "
        "report.json and timings.json into the folder OUT (replaced only once complete).",
        epilog="example:\n  igljoin join host.ply guest.obj -o out/j1 --host-loop 0 "
        "--guest-start 0.5,1,2 -O smooth_weight=5",
        formatter_class=_Formatter,
    )
    p.add_argument("host", type=Path, metavar="HOST", help="host mesh (.ply .obj .off .stl)")
    p.add_argument("guest", type=Path, metavar="GUEST", help="guest mesh")
    p.add_argument("-o", "--out", type=Path, required=True, metavar="OUT", help="output folder")
    _add_curve_flags(p)
    _add_option_flags(p)
    p.add_argument(
        "--snapshot", action="store_true", help="also render OUT/snapshot.png (needs the viz extra)"
    )
    p.add_argument("--json", action="store_true", help="print the result as JSON on stdout")
    p.add_argument("--formats", type=_formats, metavar="LIST", help=_FORMATS_HELP)
    p.add_argument(
        "--no-progress",
        action="store_true",
        help="no status line on stderr (shown only on a terminal)",
    )
    p.set_defaults(func=_cmd_join, parser=p)

    p = sub.add_parser(
        "batch",
        help="join every case folder of CASES (local processes or dask)",
        description="Run every case folder of CASES (host.*, guest.*, join.toml) and write "
        "OUT/<case>/ plus OUT/summary.csv and OUT/summary.json. Exits 1 and says how many "
        "cases failed if any did; the other cases are complete either way.",
        epilog="examples:\n  igljoin batch cases/ -o out/ --workers 4\n"
        "  igljoin batch cases/ -o out/ --resume          # after an interruption\n"
        "  igljoin batch cases/ -o out/ --scheduler tcp://10.0.0.5:8786",
        formatter_class=_Formatter,
    )
    p.add_argument("cases", type=Path, metavar="CASES", help="folder of case folders")
    p.add_argument("-o", "--out", type=Path, required=True, metavar="OUT", help="output folder")
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--workers",
        type=_nonnegative_int,
        metavar="N",
        help="local worker processes (default: one per CPU; 0 = in this process)",
    )
    where.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on the dask cluster at ADDRESS (needs the dask extra)",
    )
    where.add_argument(
        "--dask-local",
        type=_positive_int,
        metavar="N",
        help="start a local dask cluster of N workers for the batch",
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="skip cases whose outputs are complete and whose inputs and options are unchanged",
    )
    p.add_argument(
        "--snapshots",
        action="store_true",
        help="also render snapshot.png per case (needs the viz extra)",
    )
    p.add_argument("--formats", type=_formats, metavar="LIST", help=_FORMATS_HELP)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    p.set_defaults(func=_cmd_batch, parser=p)

    p = sub.add_parser(
        "clean",
        help="repair a mesh (and optionally resample it) with pymeshlab",
        description="Remove duplicate/unreferenced vertices, duplicate, zero-area and sliver "
        "faces, repair non-manifold edges and vertices and orientation; optionally close "
        "small holes and resample. Writes OUT; exits 1 if problems remain.",
        epilog="example:\n  igljoin clean scan.ply -o clean.ply --close-holes --keep-loop 0",
        formatter_class=_Formatter,
    )
    p.add_argument("input", type=Path, metavar="IN", help="mesh to repair (not modified)")
    p.add_argument(
        "-o", "--out", type=Path, required=True, metavar="OUT", help="repaired mesh file"
    )
    p.add_argument("--close-holes", action="store_true", help="fill small holes")
    p.add_argument(
        "--max-hole-edges",
        type=_positive_int,
        default=30,
        metavar="N",
        help="largest hole filled, in edges (default 30)",
    )
    keep = p.add_mutually_exclusive_group()
    keep.add_argument(
        "--keep-loop",
        type=_nonnegative_int,
        metavar="K",
        help="boundary loop to keep open (index in the cleaned mesh)",
    )
    keep.add_argument(
        "--keep-point",
        type=_point_arg,
        metavar="X,Y,Z",
        help="keep open the boundary loop nearest this point",
    )
    p.add_argument(
        "--sliver-ratio",
        type=float,
        default=None,
        metavar="R",
        help="aspect ratio below which a face is a sliver (default 1e-3)",
    )
    p.add_argument(
        "--min-component-faces",
        type=_nonnegative_int,
        default=10,
        metavar="N",
        help="remove loose pieces with fewer faces (default 10)",
    )
    p.add_argument(
        "--resample",
        type=_positive_float,
        metavar="EDGE",
        help="then remesh to edge length EDGE, keeping the boundary",
    )
    p.add_argument("--json", action="store_true", help="print the report as JSON on stdout")
    p.set_defaults(func=_cmd_clean, parser=p)

    p = sub.add_parser(
        "info",
        help="describe a mesh: counts, boundary loops, problems",
        description="Vertex and face counts, boundary loops (sizes and lengths) and the "
        "problems that stop a join: degenerate, zero-area, sliver and duplicate faces, "
        "non-manifold edges and vertices, inconsistent orientation, unreferenced and "
        "duplicate vertices, components.",
        formatter_class=_Formatter,
    )
    p.add_argument("mesh", type=Path, metavar="MESH", help="mesh file")
    p.add_argument("--json", action="store_true", help="print as JSON on stdout")
    p.set_defaults(func=_cmd_info, parser=p)

    p = sub.add_parser(
        "demo",
        help="run the paper's experiments (what `make demo` runs)",
        description="Join the paper's six samples with and without the smooth-join term and "
        "write meshes, a table, the paper's claims checked and (with the viz extra) figures.",
        formatter_class=_Formatter,
    )
    p.add_argument(
        "--out",
        type=Path,
        default=Path("out/demo"),
        metavar="DIR",
        help="output folder (default out/demo)",
    )
    p.add_argument(
        "--resolution",
        type=_positive_float,
        default=1.0,
        metavar="R",
        help="phantom resolution (1 = the paper's sizes)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print the result as JSON on stdout")
    p.set_defaults(func=_cmd_demo, parser=p)

    for name, func, text in (
        ("render", _cmd_render, "join and render a picture of the result (headless)"),
        ("inspect", _cmd_inspect, "join and open the interactive polyscope inspection"),
    ):
        p = sub.add_parser(
            name,
            help=text,
            description=f"{text[0].upper()}{text[1:]}. Give a case folder, or HOST and GUEST "
            "files with curve flags. Needs the viz extra (polyscope).",
            formatter_class=_Formatter,
        )
        p.add_argument(
            "inputs",
            type=Path,
            nargs="+",
            metavar="CASE | HOST GUEST",
            help="a case folder, or the host and guest mesh files",
        )
        if name == "render":
            p.add_argument(
                "-o", "--out", type=Path, required=True, metavar="PNG", help="picture file"
            )
            p.add_argument(
                "--view",
                choices=("side", "along", "both"),
                default="side",
                help="across the seam, along it, or both (default side)",
            )
            p.add_argument(
                "--size",
                type=_positive_int,
                nargs=2,
                metavar=("W", "H"),
                help="picture size in pixels",
            )
        _add_curve_flags(p)
        _add_option_flags(p)
        p.set_defaults(func=func, parser=p)
    return parser


# --------------------------------------------------------------------------- helpers


def _curve_from_args(args: argparse.Namespace, role: str) -> dict | None:
    table: dict[str, Any] = {}
    for key in ("loop", "start", "end", "via", "indices"):
        value = getattr(args, f"{role}_{key}", None)
        if value is not None:
            table[key] = value
    return table or None


def _options_from_args(args: argparse.Namespace) -> dict:
    options: dict[str, Any] = {}
    for path, value in args.option:
        node = options
        for key in path[:-1]:
            child = node.get(key)
            if not isinstance(child, dict):
                child = {} if not isinstance(child, bool) or child else {"enabled": False}
                node[key] = child
            node = child
        node[path[-1]] = value
    if args.no_smooth:
        options["smooth"] = False
    if args.cleanup and "cleanup" not in options:
        options["cleanup"] = True
    if (args.resample or args.target_edge is not None) and "resample" not in options:
        options["resample"] = {"target_edge": args.target_edge} if args.target_edge else True
    return options


def _spec_from_args(parser: argparse.ArgumentParser, args: argparse.Namespace, host, guest):
    from .spec import CaseSpec

    try:
        return CaseSpec.make(
            host,
            guest,
            _curve_from_args(args, "host"),
            _curve_from_args(args, "guest"),
            _options_from_args(args),
        )
    except SpecError as exc:
        parser.error(str(exc).removeprefix("arguments: "))


def _print_json(data: Any) -> None:
    from .plain import plain_json

    print(json.dumps(plain_json(data), indent=2, allow_nan=False))


def _fmt(value: Any, spec: str = ".3g", unit: str = "") -> str:
    return "n/a" if value is None else f"{value:{spec}}{unit}"


def _row_lines(row: dict) -> list[str]:
    return [
        f"  converged: {row['converged']} after {row['iterations']} iterations",
        f"  seam gap max {_fmt(row['seam_gap_max'])} ({_fmt(row['seam_gap_relative_max'])} of "
        "a host seam edge)",
        f"  crease mean {_fmt(row['crease_mean'], '.2f', '°')}, "
        f"max {_fmt(row['crease_max'], '.2f', '°')}",
        f"  area change mean {_fmt(row['area_change_mean'], '.1%')}, "
        f"max {_fmt(row['area_change_max'], '.1%')}",
    ]


def _warning_lines(warnings: list) -> list[str]:
    """The quality warnings of a join, one line each (``docs/warnings.md``), or "none"."""
    if not warnings:
        return ["  warnings: none"]
    lines = [f"  warnings: {len(warnings)} (see docs/warnings.md)"]
    for w in warnings:
        if isinstance(w, dict):
            lines.append(f"    {w.get('code')}: {w.get('message')}")
        else:  # a QualityWarning
            lines.append(f"    {w.code}: {w.message}")
    return lines


def _report_warnings(folder: Path) -> list:
    """``report["warnings"]`` of a case output folder (empty if unreadable)."""
    try:
        report = json.loads((folder / "report.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return []
    found = report.get("warnings") if isinstance(report, dict) else None
    return found if isinstance(found, list) else []


def _viz():
    try:
        from . import viz
    except ImportError as exc:
        raise MissingExtraError(
            f"igljoin.viz is not available in this installation ({exc}); install the viz "
            "extra: pip install 'igljoin[viz]'"
        ) from None
    return viz


# --------------------------------------------------------------------------- commands


class SolveStatus:
    """A one-line status of a long solve on a terminal: iteration, energy, seconds.

    Use it as the ``progress`` callable of a join. Nothing is drawn before
    the iteration has run ``delay`` seconds (fast joins stay quiet) unless
    :meth:`begin` drew a line already; the line is redrawn at most every
    ``interval`` seconds and erased by :meth:`close`.

    Parameters
    ----------
    stream : text stream
        Where to draw (``sys.stderr`` on a terminal).
    delay : float
        Seconds of iteration before the first draw.
    interval : float
        Least seconds between two draws.
    """

    def __init__(self, stream, delay: float = 1.0, interval: float = 0.2):
        self.stream = stream
        self.delay = delay
        self.interval = interval
        self._drawn_at: float | None = None
        self._width = 0

    def begin(self, text: str) -> None:
        """Draw ``text`` at once (e.g. what runs before the first iteration).

        The first iteration then replaces it without waiting for ``delay``.
        """
        self._draw(text)
        self._drawn_at = None

    def __call__(self, progress) -> None:
        if self._drawn_at is None:
            if progress.elapsed < self.delay and not self._width:
                return
        elif progress.elapsed - self._drawn_at < self.interval:
            return
        self._draw(
            f"{PROG}: joining, iteration {progress.iteration} (at most "
            f"{progress.max_iterations}), energy {progress.energy:.6g}, "
            f"{progress.elapsed:.0f} s"
        )
        self._drawn_at = progress.elapsed

    def _draw(self, text: str) -> None:
        self.stream.write("\r" + text.ljust(self._width))
        self.stream.flush()
        self._width = len(text)

    def close(self) -> None:
        """Erase the line (if one was drawn)."""
        if self._width:
            self.stream.write("\r" + " " * self._width + "\r")
            self.stream.flush()
            self._width = 0


def _cmd_join(parser, args) -> int:
    from .pipeline import run_case

    spec = _spec_from_args(parser, args, args.host, args.guest)
    status = None if args.no_progress or not sys.stderr.isatty() else SolveStatus(sys.stderr)
    if status is not None:
        status.begin(f"{PROG}: reading, checking and factoring (large guests take a while)")
    try:
        row = run_case(
            spec,
            args.out,
            snapshots=args.snapshot,
            record_errors=False,
            progress=status,
            formats=args.formats,
        )
    finally:
        if status is not None:
            status.close()
    from .outputs import MANIFEST, read_manifest

    files = sorted(set(read_manifest(args.out)) - {MANIFEST})  # igljoin's files only
    warnings = _report_warnings(args.out)
    if args.json:
        _print_json({"out": args.out, "files": files, "summary": row, "warnings": warnings})
        return 0
    print(f"joined {args.guest} to {args.host} -> {args.out}")
    print("\n".join(_row_lines(row)))
    print("\n".join(_warning_lines(warnings)))
    print(f"  wrote {', '.join(files)}")
    return 0


def _cmd_batch(parser, args) -> int:
    from .pipeline import run_batch

    summary = run_batch(
        args.cases,
        args.out,
        workers=args.workers,
        scheduler=args.scheduler,
        dask_local=args.dask_local,
        resume=args.resume,
        progress=not args.no_progress,
        snapshots=args.snapshots,
        formats=args.formats,
    )
    if args.json:
        _print_json(summary.to_json())
    else:
        skipped = f", {len(summary.skipped)} up to date (skipped)" if summary.skipped else ""
        print(
            f"{summary.n_cases} cases: {summary.n_cases - len(summary.failed)} ok "
            f"({len(summary.warned)} with warnings), {len(summary.failed)} failed{skipped}; "
            f"{summary.seconds:.1f} s"
        )
        for row in summary.rows:
            if row["status"] != "ok":
                print(f"  {row['name']}: failed at {row['step']}: {row['error_message']}")
            elif row.get("warnings"):
                codes = row["warnings"].split(";")
                many = "s" if len(codes) != 1 else ""
                print(f"  {row['name']}: ok, {len(codes)} warning{many}: {', '.join(codes)}")
        if summary.warned:
            print("  (each case's report.json says what the warnings mean; see docs/warnings.md)")
        if summary.files:
            print(f"summary: {summary.files['summary_csv']}")
    if summary.summary_error is not None:
        print(
            f"{PROG}: error: the summary could not be written ({summary.summary_error}); "
            "the rows above are its only copy",
            file=sys.stderr,
        )
    if summary.unrecorded:
        print(
            f"{PROG}: error: the outcome of {len(summary.unrecorded)} case(s) could not be "
            f"written into their folders: {', '.join(summary.unrecorded)}; free space and "
            "rerun with --resume",
            file=sys.stderr,
        )
    if summary.summary_error is not None or summary.unrecorded:
        if args.json:
            return 1
        for row in summary.rows:
            if row["status"] == "ok" and not row.get("warnings"):
                print(f"  {row['name']}: ok")
    if not summary.ok or summary.summary_error is not None:
        print(f"{PROG}: {summary.message()}", file=sys.stderr)
        return 1
    return 0


def _problem_lines(info: dict) -> list[str]:
    found = {k: v for k, v in info["problems"].items() if v}
    if not found:
        return ["problems: none"]
    return ["problems:"] + [f"  {k.replace('_', ' ')}: {v}" for k, v in found.items()]


def _cmd_info(parser, args) -> int:
    from .clean import diagnose
    from .io import read_mesh

    mesh = read_mesh(args.mesh)
    info = diagnose(mesh)
    if args.json:
        _print_json({"file": args.mesh, **info})
        return 0
    print(
        f"{args.mesh}: {info['vertices']} vertices, {info['faces']} faces, mean edge "
        f"{info['mean_edge']:.4g}, bounding box diagonal {info['bbox_diagonal']:.4g}"
    )
    sizes = info["component_faces"]
    print(
        f"components: {info['components']} (faces: {', '.join(map(str, sizes))}"
        f"{', ...' if info['components'] > len(sizes) else ''})"
    )
    loops = info["loops"]
    if loops is None:
        print(
            f"boundary: {info['boundary_edges']} boundary edges; loops are not defined while "
            "edges are non-manifold (run `igljoin clean`)"
        )
    elif not loops:
        print("boundary loops: none (closed surface)")
    else:
        print(f"boundary loops: {len(loops)}")
        for k, lp in enumerate(loops):
            print(f"  loop {k}: {lp['size']} vertices, length {lp['length']:.4g}")
    print("\n".join(_problem_lines(info)))
    return 0


def _cmd_clean(parser, args) -> int:
    from .clean import SLIVER_RATIO, clean, resample
    from .io import read_mesh, write_mesh

    if args.out.resolve() == args.input.resolve():
        parser.error(f"OUT {args.out} is the input file; write the repaired mesh elsewhere")
    mesh = read_mesh(args.input)
    keep = None
    if args.keep_loop is not None:
        keep = args.keep_loop
    elif args.keep_point is not None:
        keep = {"start": args.keep_point}
    out, report = clean(
        mesh,
        close_holes=args.close_holes,
        keep_boundary=keep,
        max_hole_edges=args.max_hole_edges,
        sliver_ratio=SLIVER_RATIO if args.sliver_ratio is None else args.sliver_ratio,
        min_component_faces=args.min_component_faces,
    )
    result: dict[str, Any] = {"input": args.input, "out": args.out, "clean": report.to_json()}
    if args.resample is not None:
        out, rrep = resample(out, args.resample)
        result["resample"] = rrep.to_json()
    write_mesh(args.out, out)
    remaining = {k: v for k, v in report.after["problems"].items() if v}
    if args.json:
        _print_json(result)
    else:
        print(f"cleaned {args.input} -> {args.out}: {out.n_vertices} vertices, {out.n_faces} faces")
        for key, n in report.fixes.items():
            if n:
                print(f"  {key.replace('_', ' ')}: {n}")
        if not report.total:
            print("  nothing to repair")
        if "resample" in result:
            r = result["resample"]
            print(
                f"  resampled to edge {r['target_edge']:.4g}: mean edge now "
                f"{r['after']['mean_edge']:.4g}"
            )
    if remaining:
        listed = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in remaining.items())
        print(f"{PROG}: problems remain after cleaning: {listed}", file=sys.stderr)
        return 1
    return 0


def _cmd_demo(parser, args) -> int:
    from . import demo

    result = demo.run(args.out, resolution=args.resolution, progress=not args.no_progress)
    if args.json:
        _print_json(result)
        return 0
    paths = result.get("paths") or {}
    if "table_md" in paths:
        print(Path(paths["table_md"]).read_text(encoding="utf-8"))
    print(f"demo written to {args.out}")
    for key, path in paths.items():
        print(f"  {key}: {path}")
    for note in result.get("notes") or []:
        print(f"  note: {note}")
    return 0


def _solved_from_inputs(parser, args):
    from .pipeline import solve_case
    from .spec import load_case

    if len(args.inputs) == 1:
        if not args.inputs[0].is_dir():
            parser.error("give a case folder, or HOST and GUEST mesh files")
        spec = load_case(args.inputs[0])
    elif len(args.inputs) == 2:
        spec = _spec_from_args(parser, args, *args.inputs)
    else:
        parser.error(f"expected a case folder or HOST GUEST, got {len(args.inputs)} paths")
    return solve_case(spec)


def _cmd_render(parser, args) -> int:
    viz = _viz()
    solved = _solved_from_inputs(parser, args)
    kwargs: dict[str, Any] = {"view": args.view, "title": solved.spec.name}
    if args.size:
        kwargs["size"] = tuple(args.size)
    path = viz.render(solved.result, args.out, **kwargs)
    print(f"rendered {solved.spec.name} -> {path}")
    print("\n".join(_warning_lines(list(solved.result.warnings))))
    return 0


class NoDisplayError(MissingExtraError):
    """``igljoin inspect`` was run where no window can open."""


def _cmd_inspect(parser, args) -> int:
    viz = _viz()
    from .viz._backend import has_display

    if not has_display():  # checked before the join: the window could never open
        raise NoDisplayError(
            "inspect opens an interactive window, but there is no display here (neither "
            "DISPLAY nor WAYLAND_DISPLAY is set); render a picture instead: igljoin render "
            f"{' '.join(map(str, args.inputs))} -o picture.png (same curve and option flags)"
        )
    solved = _solved_from_inputs(parser, args)
    viz.inspect(solved.result, title=solved.spec.name)
    return 0


# --------------------------------------------------------------------------- main


def _one_line(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.strerror:
        text = exc.strerror
        if exc.filename is not None and str(exc.filename) not in text:
            text += f": {exc.filename}"
        return text
    return str(exc) or type(exc).__name__


def _silence_stdout() -> None:
    """Point stdout at /dev/null so that the interpreter's final flush cannot fail again."""
    import os

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):
        pass


def main(argv: list[str] | None = None) -> int:
    """Run the ``igljoin`` command line.

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name (default ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit code: 0 success, 1 failure (a failed join, file error or failed
        cases), 2 usage error (argparse exits with 2 directly).
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help(sys.stderr)
        return 2
    try:
        code = args.func(args.parser, args)
        sys.stdout.flush()  # inside the try: a closed pipe shows up here, not at exit
        return code
    except BrokenPipeError:  # the reader went away (`| head`): end quietly, as cat does
        _silence_stdout()
        return 141  # 128 + SIGPIPE, what a shell reports for a command ended by a closed pipe
    except (IgljoinError, OSError, MissingExtraError) as exc:
        print(f"{PROG}: error: {_one_line(exc)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
