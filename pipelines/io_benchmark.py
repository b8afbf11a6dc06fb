"""Benchmark mesh reading and writing: every format on a 90k-vertex / 179k-face grid.

Usage::

    python pipelines/io_benchmark.py               # 5 repeats, prints a Markdown table
    python pipelines/io_benchmark.py --repeats 9 --json io.json

The grid is a 300 x 300 height field (90,000 vertices, 178,802 triangles)
with two float64 vertex attributes and one face attribute, written by
:func:`igljoin.write_mesh` in each format (OBJ, OFF, ASCII and binary STL,
binary PLY without face attributes, ASCII PLY with them, VTU, VTK). Each
file is then read back ``--repeats`` times by :func:`igljoin.read_mesh`
(and, for comparison, by the record-by-record reference parsers that the
vectorised readers fall back to for unusual blocks); the table reports
medians in seconds, wall-clock and CPU time of the process (the machine is
shared: CPU time is less disturbed by other load; compare rows of one run,
not runs of different days).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from functools import partial
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from igljoin.io import obj, off, read_mesh, stl, write_mesh  # noqa: E402
from igljoin.mesh import Mesh  # noqa: E402


def grid(n: int = 300, seed: int = 0) -> Mesh:
    """A wavy n x n height-field grid with full-precision coordinates and attributes."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.linspace(0.0, 1.0, n), np.linspace(0.0, 1.0, n))
    V = np.column_stack([x.ravel(), y.ravel(), 0.1 * np.sin(7 * x.ravel()) * np.cos(5 * y.ravel())])
    V += 1e-4 * rng.standard_normal(V.shape)  # no short decimal expansions
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = i[:-1, :-1].ravel(), i[1:, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, 1:].ravel()
    F = np.vstack([np.column_stack([a, b, c]), np.column_stack([b, d, c])])
    return Mesh(
        V,
        F,
        {"displacement": rng.random(n * n), "strain": rng.random(n * n)},
        {"area_ratio": rng.random(F.shape[0])},
    )


def _median_seconds(fn, repeats: int, clock=time.perf_counter) -> float:
    times = []
    for _ in range(repeats):
        t = clock()
        fn()
        times.append(clock() - t)
    return statistics.median(times)


def _reference(module, path: Path):
    """Run a text reader with its vectorised path switched off (every block by the reference)."""
    saved = module._fast
    module._fast = lambda *args: False
    try:
        return read_mesh(path)
    finally:
        module._fast = saved


def run(repeats: int) -> list[dict]:
    mesh = grid()
    plain = Mesh(mesh.V, mesh.F, mesh.vertex_attributes)  # no face attributes: binary PLY
    cases = [
        ("OBJ", "g.obj", mesh, {}, obj),
        ("OFF", "g.off", mesh, {}, off),
        ("STL binary", "b.stl", mesh, {"binary": True}, None),
        ("STL ASCII", "a.stl", mesh, {"binary": False}, stl),
        ("PLY binary (vertex attributes)", "b.ply", plain, {}, None),
        ("PLY ASCII (face attributes)", "a.ply", mesh, {}, None),
        ("VTU (write only)", "g.vtu", mesh, {}, None),
        ("VTK legacy (write only)", "g.vtk", mesh, {}, None),
    ]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for label, name, m, kwargs, module in cases:
            path = Path(tmp) / name
            write = _median_seconds(partial(write_mesh, path, m, **kwargs), max(1, repeats // 2))
            row = {
                "format": label,
                "vertices": m.n_vertices,
                "faces": m.n_faces,
                "megabytes": round(path.stat().st_size / 1e6, 1),
                "write_s": round(write, 3),
            }
            if name.endswith((".obj", ".off", ".stl", ".ply")):
                back = read_mesh(path)
                assert back.n_faces == m.n_faces and back.n_vertices == m.n_vertices, label
                row["read_s"] = round(_median_seconds(partial(read_mesh, path), repeats), 3)
                cpu = _median_seconds(partial(read_mesh, path), repeats, time.process_time)
                row["read_cpu_s"] = round(cpu, 3)
            if module is not None:
                reference = _reference(module, path)
                np.testing.assert_array_equal(reference.V, back.V)
                np.testing.assert_array_equal(reference.F, back.F)
                row["reference_read_s"] = round(
                    _median_seconds(partial(_reference, module, path), 1), 3
                )
            rows.append(row)
            print(row, file=sys.stderr)
    return rows


def markdown(rows: list[dict]) -> str:
    lines = [
        "| format | MB | write (s) | read (s) | read, CPU (s) | reference parser (s) |",
        "| --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in rows:
        read, cpu = r.get("read_s", ""), r.get("read_cpu_s", "")
        ref = r.get("reference_read_s", "")
        lines.append(
            f"| {r['format']} | {r['megabytes']} | {r['write_s']} | {read} | {cpu} | {ref} |"
        )
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="reads per format (median)")
    parser.add_argument("--json", type=Path, help="also write the rows to this JSON file")
    args = parser.parse_args(argv)
    rows = run(args.repeats)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    print(markdown(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
