"""The bad-input corpus: every bad input gets a clear error naming the problem and the fix.

Each case is (name, what the user did, a callable that does it, the exact error
type, substrings the message must contain). ``docs/errors.md`` is generated from
this corpus: run ``IGLJOIN_UPDATE_DOCS=1 pytest tests/test_bad_input.py`` after
changing a message.
"""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

import igljoin
from igljoin import phantoms

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "errors.md"


@dataclass
class Case:
    name: str
    action: Callable[[Path], object]
    error: type
    needles: tuple[str, ...]


def _grid(nx=6, ny=5):
    x, y = np.meshgrid(np.linspace(0, 1, nx), np.linspace(0, 1, ny))
    V = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    i = np.arange(nx - 1)[None, :] + nx * np.arange(ny - 1)[:, None]
    i = i.ravel()
    F = np.concatenate([np.stack([i, i + 1, i + nx + 1], 1), np.stack([i, i + nx + 1, i + nx], 1)])
    return V, F


_PATCH = phantoms.paper_sample("partial_patch", "equal", resolution=0.3)
_STRIP = phantoms.paper_sample("open_strip", "equal", resolution=0.5)
HOST, GUEST, HC = _PATCH.host, _PATCH.guest, _PATCH.host_curve


def _guest(V=None, F=None):
    return (GUEST.V if V is None else V, GUEST.F if F is None else F)


def _join(guest=None, host=None, hc=HC, gc=None, **kw):
    return igljoin.join(
        HOST if host is None else host, GUEST if guest is None else guest, hc, gc, **kw
    )


@contextlib.contextmanager
def _entry_limit_lowered(module):
    """``module.MAX_MODEL_ENTRIES`` lowered to 1,000 for the block, restored after it."""
    before = module.MAX_MODEL_ENTRIES
    module.MAX_MODEL_ENTRIES = 1_000
    try:
        yield
    finally:
        module.MAX_MODEL_ENTRIES = before


def _two_level_past_its_limit():
    """A two-level join whose model is over ``MAX_MODEL_ENTRIES``, lowered to 1,000."""
    from igljoin import twolevel

    with _entry_limit_lowered(twolevel):
        return _join(preconditioner="two-level")


def _newton_model_past_its_limit():
    """The Gauss–Newton model of a join whose count is over ``MAX_MODEL_ENTRIES``, lowered
    to 1,000."""
    from igljoin import newton

    solver = igljoin.JoinSolver(HOST, GUEST, HC)
    with _entry_limit_lowered(newton):
        return newton.NewtonModel(solver.solver)


def _write(tmp: Path, name: str, data: bytes) -> Path:
    p = tmp / name
    p.write_bytes(data)
    return p


def _with_row(V, row, value):
    V = np.array(V)
    V[row] = value
    return V


def _interior(mesh):
    on = np.concatenate(igljoin.boundary_loops(mesh.F))
    return int(np.setdiff1d(np.arange(mesh.n_vertices), on)[0])


def _extra_face(F, face):
    return np.vstack([F, [face]])


def _non_manifold_edge():
    V, F = GUEST.V, GUEST.F
    a, b, _ = F[len(F) // 2]
    top = V[[a, b]].mean(axis=0) + [0.0, 0.0, 1.0]
    return np.vstack([V, top]), _extra_face(F, [a, b, len(V)])


def _non_manifold_vertex():
    V, F = _grid()
    V2 = np.vstack([V, V[[0, 1]] + [0, 0, 1.0], [[0.5, 0.5, 1.0]]])
    fan = [len(V), len(V) + 1, len(V) + 2]
    # a second triangle touching the grid only at vertex 7 (an interior vertex)
    V2[len(V)] = V[7]
    F2 = np.vstack([F, [[7, len(V) + 1, len(V) + 2]]])
    del fan
    return V2, F2


def _flipped_face():
    F = np.array(GUEST.F)
    F[len(F) // 2] = F[len(F) // 2][::-1]
    return GUEST.V, F


def _zero_area(on_seam: bool):
    V, F = np.array(GUEST.V), np.array(GUEST.F)
    loop = igljoin.boundary_loops(F)[0]
    if on_seam:
        f = int(np.flatnonzero(np.isin(F, loop).any(axis=1))[0])
    else:
        f = int(np.flatnonzero(~np.isin(F, loop).any(axis=1))[0])
    a, b, c = F[f]
    # move one vertex onto the midpoint of the other two: the face has zero area
    moving = c if c not in loop else (b if b not in loop else a)
    others = [x for x in (a, b, c) if x != moving]
    V[moving] = V[others].mean(axis=0)
    return V, F


def _duplicate_vertex():
    V, F = np.array(GUEST.V), np.array(GUEST.F)
    v = _interior(GUEST)
    V2 = np.vstack([V, V[v]])
    f = int(np.flatnonzero((F == v).any(axis=1))[0])
    F[f][F[f] == v] = len(V)
    return V2, F


def _two_components():
    V, F = GUEST.V, GUEST.F
    W = V + [0.0, 0.0, 40.0]
    return np.vstack([V, W]), np.vstack([F, F + len(V)])


def _only_seam():
    P = HOST.V[HC]
    k = len(HC)
    F = np.stack([np.zeros(k - 2, int), np.arange(1, k - 1), np.arange(2, k)], axis=1)
    return P + [1.0, 0.0, 0.0], F


def _tetrahedron():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return V, F


def _case_folder(tmp: Path, toml: str | None, host: bool = True, name: str = "case") -> Path:
    """A case folder with the patch sample's meshes and the given join.toml."""
    folder = tmp / name
    folder.mkdir(exist_ok=True)
    if host:
        igljoin.write_mesh(folder / "host.ply", HOST)
    igljoin.write_mesh(folder / "guest.ply", GUEST)
    if toml is not None:
        (folder / "join.toml").write_text(toml, encoding="utf-8")
    return folder


def _corpus() -> list[Case]:
    loops = igljoin.boundary_loops(HOST.F)
    outer, hole = loops[0], loops[1]
    strip = _STRIP
    cases = [
        Case(
            "empty file",
            lambda t: igljoin.read_mesh(_write(t, "empty.ply", b"")),
            igljoin.MeshReadError,
            ("empty",),
        ),
        Case(
            "truncated PLY",
            lambda t: igljoin.read_mesh(
                _write(
                    t,
                    "cut.ply",
                    b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                    b"property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
                    b"end_header\n0 0 0\n1 0 0\n",
                )
            ),
            igljoin.MeshReadError,
            ("truncated",),
        ),
        Case(
            "unknown format",
            lambda t: igljoin.read_mesh(_write(t, "mesh.xyz", b"1 2 3\n")),
            igljoin.MeshReadError,
            (".xyz", ".ply"),
        ),
        Case(
            "binary garbage named .ply",
            lambda t: igljoin.read_mesh(_write(t, "noise.ply", bytes(range(256)) * 8)),
            igljoin.MeshReadError,
            ("noise.ply",),
        ),
        Case(
            "binary garbage named .obj",
            lambda t: igljoin.read_mesh(_write(t, "noise.obj", bytes(range(256)) * 8)),
            igljoin.MeshReadError,
            ("noise.obj",),
        ),
        Case(
            "missing file",
            lambda t: igljoin.read_mesh(t / "nope.obj"),
            FileNotFoundError,
            ("nope.obj",),
        ),
        Case(
            "NaN coordinates",
            lambda t: _join(_guest(_with_row(GUEST.V, 3, np.nan))),
            igljoin.MeshError,
            ("NaN or infinite", "remove or repair"),
        ),
        Case(
            "infinite coordinates",
            lambda t: _join(_guest(_with_row(GUEST.V, 3, np.inf))),
            igljoin.MeshError,
            ("NaN or infinite",),
        ),
        Case(
            "vertex array of wrong shape",
            lambda t: _join(_guest(GUEST.V[:, :2])),
            igljoin.MeshError,
            ("(n, 3)",),
        ),
        Case(
            "face index out of range",
            lambda t: _join(_guest(F=_extra_face(GUEST.F, [0, 1, GUEST.n_vertices]))),
            igljoin.MeshError,
            ("range", "0-based"),
        ),
        Case(
            "negative face index",
            lambda t: _join(_guest(F=_extra_face(GUEST.F, [0, 1, -1]))),
            igljoin.MeshError,
            ("range",),
        ),
        Case(
            "face repeating a vertex",
            lambda t: _join(_guest(F=_extra_face(GUEST.F, [4, 4, 5]))),
            igljoin.MeshError,
            ("repeat a vertex", "igljoin.clean"),
        ),
        Case(
            "zero-area face on the seam",
            lambda t: _join(_guest(*_zero_area(True))),
            igljoin.MeshError,
            ("zero area", "igljoin.clean"),
        ),
        Case(
            "zero-area face off the seam",
            lambda t: _join(_guest(*_zero_area(False))),
            igljoin.MeshError,
            ("zero area", "igljoin.clean"),
        ),
        Case(
            "duplicate faces",
            lambda t: _join(_guest(F=np.vstack([GUEST.F, GUEST.F[:1, ::-1]]))),
            igljoin.MeshError,
            ("duplicated", "igljoin.clean"),
        ),
        Case(
            "duplicate vertices",
            lambda t: _join(_guest(*_duplicate_vertex())),
            igljoin.MeshError,
            ("share their position", "igljoin.clean"),
        ),
        Case(
            "unreferenced vertices",
            lambda t: _join(_guest(np.vstack([GUEST.V, [[0.0, 0.0, 0.0]]]))),
            igljoin.MeshError,
            ("unreferenced", "igljoin.clean"),
        ),
        Case(
            "non-manifold edge",
            lambda t: _join(_guest(*_non_manifold_edge())),
            igljoin.MeshError,
            ("more than two faces", "igljoin.clean"),
        ),
        Case(
            "non-manifold vertex",
            lambda t: _join(_guest(*_non_manifold_vertex())),
            igljoin.MeshError,
            ("non-manifold", "igljoin.clean"),
        ),
        Case(
            "inconsistently oriented faces",
            lambda t: _join(_guest(*_flipped_face())),
            igljoin.MeshError,
            ("inconsistently oriented", "igljoin.clean"),
        ),
        Case(
            "guest without a boundary",
            lambda t: _join(_tetrahedron()),
            igljoin.CurveError,
            ("no boundary loop", "cut an opening"),
        ),
        Case(
            "guest that is only its seam",
            lambda t: _join(_only_seam()),
            igljoin.SolveError,
            ("no free vertex",),
        ),
        Case(
            "guest components not touching the seam",
            lambda t: _join(_two_components(), gc=igljoin.Curve(loop=0)),
            igljoin.SolveError,
            ("do not touch the seam",),
        ),
        Case(
            "curve vertex not on a boundary",
            lambda t: _join(hc=[_interior(HOST)]),
            igljoin.CurveError,
            ("not on a boundary", "boundary_loops"),
        ),
        Case(
            "start and end on different loops",
            lambda t: _join(hc=igljoin.Curve(start=int(outer[0]), end=int(hole[0]))),
            igljoin.CurveError,
            ("on loop", "must lie on one loop"),
        ),
        Case(
            "via vertex not on the loop",
            lambda t: _join(
                hc=igljoin.Curve(start=int(hole[0]), end=int(hole[9]), via=int(outer[3]))
            ),
            igljoin.CurveError,
            ("via vertex", "not on the loop"),
        ),
        Case(
            "open curve of one edge",
            lambda t: _join(hc=igljoin.Curve(start=int(hole[0]), end=int(hole[1]))),
            igljoin.CurveError,
            ("single edge", "at least two edges"),
        ),
        Case(
            "open host curve, closed guest curve",
            lambda t: _join(hc=igljoin.Curve(start=int(hole[0]), end=int(hole[9]))),
            igljoin.CurveError,
            ("both curves must be closed",),
        ),
        Case(
            "several loops and no curve given",
            lambda t: _join(hc=None),
            igljoin.CurveError,
            ("boundary loops", "loop index"),
        ),
        Case(
            "point to snap far from any boundary",
            lambda t: _join(hc=igljoin.Curve(start=[500.0, 0.0, 0.0])),
            igljoin.CurveError,
            ("farther than", "point on the boundary"),
        ),
        Case(
            "curve indices not consecutive",
            lambda t: _join(hc=hole[::2]),
            igljoin.CurveError,
            ("not consecutive",),
        ),
        Case(
            "host curve of length zero",
            lambda t: igljoin.join(
                strip.host,
                (np.array(strip.guest.V), strip.guest.F),
                [int(strip.host_curve[0])] * 3,
                strip.guest_curve,
            ),
            igljoin.CurveError,
            ("repeat a vertex",),
        ),
        Case(
            "negative weight",
            lambda t: _join(shape_weight=-1.0),
            igljoin.OptionsError,
            ("shape_weight", "finite number from 0 to 1e+06"),
        ),
        Case(
            "zero iterations",
            lambda t: _join(max_iterations=0),
            igljoin.OptionsError,
            ("max_iterations", "an integer from 1 to 1,000,000"),
        ),
        Case(
            "unknown option",
            lambda t: _join(smoothness=3),
            igljoin.OptionsError,
            ("unknown join options", "smooth_weight"),
        ),
        Case(
            "progress that is not callable",
            lambda t: _join(progress="bar"),
            igljoin.OptionsError,
            ("progress='bar' must be a callable", "igljoin.SolveProgress"),
        ),
        Case(
            "stiffness of the wrong length",
            lambda t: _join(stiffness=np.ones(3)),
            igljoin.OptionsError,
            ("stiffness has 3 values",),
        ),
        Case(
            # the limit lowered to 1,000 entries stands in for a guest of millions of
            # vertices (the real limit is met only by models of several GB)
            "two-level model past its size limit",
            lambda t: _two_level_past_its_limit(),
            igljoin.OptionsError,
            ("two-level preconditioner's model would hold", "preconditioner='factored'"),
        ),
        Case(
            # as above: 1,000 entries stand in for a guest of tens of thousands of vertices
            "Gauss–Newton model past its size limit",
            lambda t: _newton_model_past_its_limit(),
            igljoin.OptionsError,
            ("Gauss–Newton model would hold", "MAX_MODEL_ENTRIES", "preconditioner='two-level'"),
        ),
        Case(
            "not a mesh",
            lambda t: _join("guest.obj"),
            igljoin.MeshError,
            ("expected an igljoin.Mesh", "read_mesh"),
        ),
        Case(
            "case folder without a host mesh",
            lambda t: igljoin.load_case(_case_folder(t, "", host=False, name="nohost")),
            igljoin.SpecError,
            ("host",),
        ),
        Case(
            "case folder with bad TOML",
            lambda t: igljoin.load_case(_case_folder(t, "[options\n", name="badtoml")),
            igljoin.SpecError,
            ("not valid TOML", "join.toml"),
        ),
        Case(
            "case folder with an unknown key",
            lambda t: igljoin.load_case(_case_folder(t, "colour = 3\n", name="unknown")),
            igljoin.SpecError,
            ("colour", "join.toml"),
        ),
        Case(
            "case folder path escaping the folder",
            lambda t: igljoin.load_case(
                _case_folder(t, 'host = "../elsewhere/host.ply"\n', name="escape")
            ),
            igljoin.SpecError,
            ("../elsewhere/host.ply", "join.toml"),
        ),
    ]
    return cases


def _npy_claiming(tmp: Path, count: int) -> Path:
    """A .npy file whose header claims ``count`` float64 values but holds 8 bytes."""
    import numpy.lib.format as npformat

    folder = _case_folder(tmp, '[options]\nstiffness = "k.npy"\n', name="npy")
    with open(folder / "k.npy", "wb") as fh:
        npformat.write_array_header_1_0(
            fh, {"descr": "<f8", "fortran_order": False, "shape": (count,)}
        )
        fh.write(b"\0" * 8)
    return folder


def _symlink_loop(tmp: Path, name: str) -> Path:
    stale = tmp / f"loop-{name.replace('.', '-')}"
    if stale.exists() or stale.is_symlink():  # the docs table reuses one folder
        shutil.rmtree(stale)
    folder = _case_folder(tmp, "", name=stale.name)
    (folder / name).unlink()
    os.symlink(name, folder / name)  # points at itself
    return folder


def _mobius(n: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """A Möbius strip: two rows of vertices joined with a half twist."""
    t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    V = np.array(
        [
            [
                (1 + w * np.cos(a / 2)) * np.cos(a),
                (1 + w * np.cos(a / 2)) * np.sin(a),
                w * np.sin(a / 2),
            ]
            for w in (-0.3, 0.3)
            for a in t
        ]
    )
    F = [[i, i + 1, n + i + 1] for i in range(n - 1)] + [
        [i, n + i + 1, n + i] for i in range(n - 1)
    ]
    F += [[n - 1, n, 0], [n - 1, 0, 2 * n - 1]]  # the twist: bottom row meets top row
    return V, np.array(F)


def _safety_corpus() -> list[Case]:
    """Inputs that once reached the user as a traceback, a hang or a misleading message."""
    from igljoin.clean import resample
    from igljoin.errors import OutputError
    from igljoin.pipeline import run_case

    return [
        Case(
            "deeply nested TOML (5,000 brackets)",
            lambda t: igljoin.load_case(
                _case_folder(t, "[options]\nx = " + "[" * 5000 + "]" * 5000 + "\n", name="deep")
            ),
            igljoin.SpecError,
            ("nested too deeply", "join.toml"),
        ),
        Case(
            "weight beyond float range (10**400)",
            lambda t: _join(shape_weight=10**400),
            igljoin.OptionsError,
            ("shape_weight=1000000000000000000000000000000000000000... (401 characters)",),
        ),
        Case(
            "time limit beyond float range",
            lambda t: _join(time_limit=10**400),
            igljoin.OptionsError,
            ("time_limit=", "out of range"),
        ),
        Case(
            "iteration cap beyond reason",
            lambda t: _join(max_iterations=10**400),
            igljoin.OptionsError,
            ("max_iterations=", "from 1 to 1,000,000"),
        ),
        Case(
            "weight far beyond the others (1e308)",
            lambda t: _join(shape_weight=1e308),
            igljoin.OptionsError,
            ("shape_weight=1e+308", "only the ratios of the weights matter"),
        ),
        Case(
            "smooth weight 1e308",
            lambda t: _join(smooth_weight=1e308),
            igljoin.OptionsError,
            ("smooth_weight=1e+308", "from 0 to 1e+06"),
        ),
        Case(
            "array given as a string option",
            lambda t: _join(smooth_mode=np.array(["robust", "paper"])),
            igljoin.OptionsError,
            ("smooth_mode=array(", "give one string"),
        ),
        Case(
            "spec loop index beyond float range",
            lambda t: igljoin.load_case(
                _case_folder(t, f"[host_curve]\nloop = {10**400}\n", name="bigloop")
            ),
            igljoin.SpecError,
            ("loop = ", "too large", "2,147,483,647"),
        ),
        Case(
            "spec resample iterations beyond float range",
            lambda t: igljoin.load_case(
                _case_folder(t, f"[options.resample]\niterations = {10**400}\n", name="bigit")
            ),
            igljoin.SpecError,
            ("iterations = ", "too large"),
        ),
        Case(
            "spec weight beyond float range",
            lambda t: igljoin.load_case(
                _case_folder(t, f"[options]\nsmooth_weight = {10**400}\n", name="bigw")
            ),
            igljoin.SpecError,
            ("smooth_weight=", "out of range"),
        ),
        Case(
            "NUL byte in a spec path",
            lambda t: igljoin.load_case(_case_folder(t, 'host = "ho\\u0000st.ply"\n', name="nul")),
            igljoin.SpecError,
            ("NUL character",),
        ),
        Case(
            "host.ply is a symbolic link loop",
            lambda t: igljoin.load_case(_symlink_loop(t, "host.ply")),
            igljoin.SpecError,
            ("symbolic link that loops",),
        ),
        Case(
            "join.toml is a symbolic link loop",
            lambda t: igljoin.load_case(_symlink_loop(t, "join.toml")),
            igljoin.SpecError,
            ("join.toml", "symbolic link that loops"),
        ),
        Case(
            ".npy stiffness whose header claims 10^12 values",
            lambda t: igljoin.load_case(_npy_claiming(t, 10**12)),
            igljoin.SpecError,
            ("k.npy", "truncated or corrupt"),
        ),
        Case(
            "clean max_hole_edges beyond C++ int",
            lambda t: igljoin.clean(GUEST, close_holes=True, max_hole_edges=2**40),
            igljoin.MeshError,
            ("max_hole_edges=1099511627776", "from 3 to 2,147,483,647"),
        ),
        Case(
            "resample iterations 2147483647 (was a hang)",
            lambda t: resample(GUEST, 1.0, iterations=2147483647),
            igljoin.MeshError,
            ("iterations=2147483647", "from 1 to 100"),
        ),
        Case(
            "resample target edge beyond float range",
            lambda t: resample(GUEST, 10**400),
            igljoin.MeshError,
            ("target_edge=", "must be a positive length"),
        ),
        Case(
            "resample to a tiny edge (was 5.7 GB, then a crash)",
            lambda t: resample(GUEST, 1e-4),
            igljoin.MeshError,
            ("faces, more than the 2,000,000 allowed", "target edge of at least"),
        ),
        Case(
            "coordinates at 1e77 (was: zero area)",
            lambda t: _join(
                igljoin.Mesh(GUEST.V * 1e77, GUEST.F), igljoin.Mesh(HOST.V * 1e77, HOST.F)
            ),
            igljoin.MeshError,
            ("host: coordinates reach", "overflow float64", "rescale"),
        ),
        Case(
            "both meshes offset by 1e15 (too few digits)",
            lambda t: _join(
                igljoin.Mesh(GUEST.V + 1e15, GUEST.F), igljoin.Mesh(HOST.V + 1e15, HOST.F)
            ),
            igljoin.MeshError,
            ("significant digits", "near the origin"),
        ),
        Case(
            "guest at 10 times the host's scale (units)",
            lambda t: _join(igljoin.Mesh(GUEST.V * 10.0, GUEST.F)),
            igljoin.MeshError,
            ("10 times as long as the host curve", "same units"),
        ),
        Case(
            "Möbius-strip guest (was: run clean)",
            lambda t: _join(_mobius()),
            igljoin.MeshError,
            ("non-orientable", "igljoin clean cannot fix this"),
        ),
        Case(
            "a point at 1e308 (was: [inf, inf, inf] is inf)",
            lambda t: _join(hc={"start": [1e308, 1e308, 1e308]}),
            igljoin.CurveError,
            ("too far out to measure", "[1e+308, 1e+308, 1e+308]"),
        ),
        Case(
            "an existing file as output folder",
            lambda t: run_case(_case_folder(t, "", name="tofile"), _write(t, "notes.txt", b"x")),
            OutputError,
            ("is an existing file, not a folder",),
        ),
    ]


CORPUS = _corpus() + _safety_corpus()


def test_corpus_has_at_least_thirty_kinds():
    assert len(CORPUS) >= 30


@pytest.mark.parametrize("case", CORPUS, ids=[c.name for c in CORPUS])
def test_bad_input_gets_a_clear_error(case, tmp_path):
    with pytest.raises(case.error) as info:
        case.action(tmp_path)
    assert type(info.value) is case.error
    msg = str(info.value)
    for needle in case.needles:
        assert needle in msg, f"{needle!r} not in {msg!r}"


@pytest.mark.parametrize("scale", [1e12, 1e-12])
def test_huge_and_tiny_coordinates_join_like_unit_ones(scale):
    """Nothing in the method has a length scale: scaled inputs give scaled results."""
    ref = _join()
    host = igljoin.Mesh(HOST.V * scale, HOST.F)
    guest = igljoin.Mesh(GUEST.V * scale, GUEST.F)
    res = igljoin.join(host, guest, HC)
    # relative 1e-6: the invariance bound; the iteration is scale-free, so only
    # rounding separates the runs
    size = np.ptp(GUEST.V, axis=0).max()
    assert np.abs(res.guest.V / scale - ref.guest.V).max() <= 1e-6 * size
    assert np.isfinite(res.guest.V).all()


def test_sliver_faces_join_without_nan():
    """Very thin (but not zero-area) triangles are tolerated."""
    V, F = np.array(GUEST.V), np.array(GUEST.F)
    v = _interior(GUEST)
    f = np.flatnonzero((F == v).any(axis=1))[0]
    others = [x for x in F[f] if x != v]
    # put v 1e-6 of an edge off the line of the other two: a sliver
    V[v] = V[others].mean(axis=0) + 1e-6 * (V[others[0]] - V[others[1]])[[1, 0, 2]]
    res = _join((V, F))
    assert np.isfinite(res.guest.V).all()


def test_guest_already_welded_to_the_host():
    """A guest whose seam already lies on the host curve joins (nothing to move)."""
    first = _join()
    again = _join(first.guest)
    assert np.isfinite(again.guest.V).all()
    # the seam was already there: the second join stops at its energy floor and moves the
    # guest by rounding only (measured 7e-16 of its size); 1e-9 leaves room for other BLAS
    size = np.ptp(GUEST.V, axis=0).max()
    n = first.guest.n_vertices
    assert np.abs(again.guest.V[:n] - first.guest.V).max() <= 1e-9 * size


def _table(tmp: Path) -> str:
    rows = []
    for case in CORPUS:
        try:
            case.action(tmp)
        except case.error as exc:
            msg = str(exc).replace("|", "\\|").replace(str(tmp), "…")
            rows.append(f"| {case.name} | `{type(exc).__name__}` | {msg} |")
    return (
        "# Bad input and what you see\n\n"
        "Every bad input is answered by an error that names the problem and the fix; "
        "none crashes, hangs or returns NaN. All of these are `ValueError` subclasses "
        "(`igljoin.IgljoinError`) except a missing file (`FileNotFoundError`). This table "
        "is generated from the test corpus in `tests/test_bad_input.py`.\n\n"
        "A join that runs but should not be trusted as it is raises no error: its result "
        "carries [quality warnings](warnings.md) instead (a crease, folds, self-intersections, "
        "a gross area change, no convergence, slivers on the seam), each with its threshold "
        "and what to do.\n\n"
        "| input | error | message |\n|---|---|---|\n" + "\n".join(rows) + "\n"
    )


def test_error_table_in_docs_is_current(tmp_path):
    table = _table(tmp_path)
    if os.environ.get("IGLJOIN_UPDATE_DOCS"):
        DOC.write_text(table, encoding="utf-8")
    assert DOC.read_text(encoding="utf-8") == table, (
        "docs/errors.md is out of date: run IGLJOIN_UPDATE_DOCS=1 pytest tests/test_bad_input.py"
    )
