"""Fuzzing with hypothesis: random meshes, curves and options through the public API.

The only exceptions allowed are igljoin's documented ones (``IgljoinError``
subclasses, all ``ValueError``); results never contain NaN/Inf and each call
finishes within a bound. ``make test`` runs the ``ci`` profile (over 2,000
examples in all); ``make fuzz`` runs the ``fuzz`` profile (many more).
"""

from __future__ import annotations

import collections
import os
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

import igljoin
from igljoin import phantoms

settings.register_profile(
    "ci", max_examples=700, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
settings.register_profile(
    "fuzz", max_examples=20_000, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

#: Examples each fuzz test of the ci/fuzz budget ran in this session (by test name).
EXAMPLES_RUN: collections.Counter = collections.Counter()

#: Seconds one call may take on these tiny meshes (a join of ~100 vertices takes
#: ~10-50 ms; the bound catches hangs, not slowness).
CALL_BOUND = 10.0


@pytest.fixture(scope="module", autouse=True)
def _kernels_loaded():
    """Join once in every smooth mode before the examples: the first call of a process
    compiles the numba kernels (or loads them from the cache), which takes seconds on a
    fresh clone of a loaded machine and is not the hang CALL_BOUND is there to catch."""
    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.3)
    for mode in ("band", "robust", "paper"):
        for acceleration in (0, 10):
            igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve, smooth_mode=mode,
                         acceleration=acceleration, max_iterations=3)  # fmt: skip


def grid(nx: int, ny: int, heights: np.ndarray, jitter: np.ndarray) -> igljoin.Mesh:
    """A (nx × ny) grid sheet with given heights (nx*ny,) and in-plane jitter (nx*ny, 2)."""
    x, y = np.meshgrid(np.arange(nx, dtype=float), np.arange(ny, dtype=float))
    V = np.stack([x.ravel(), y.ravel(), heights], axis=1)
    V[:, :2] += jitter
    i = (np.arange(nx - 1)[None, :] + nx * np.arange(ny - 1)[:, None]).ravel()
    F = np.concatenate([np.stack([i, i + 1, i + nx + 1], 1), np.stack([i, i + nx + 1, i + nx], 1)])
    return igljoin.Mesh(V, F)


@st.composite
def sheets(draw, offset=0.0):
    nx = draw(st.integers(3, 7))
    ny = draw(st.integers(3, 7))
    n = nx * ny
    h = np.array(draw(st.lists(st.floats(-0.3, 0.3), min_size=n, max_size=n)))
    j = np.array(draw(st.lists(st.floats(-0.2, 0.2), min_size=2 * n, max_size=2 * n)))
    m = grid(nx, ny, h, j.reshape(n, 2))
    return igljoin.Mesh(m.V + [0.0, 0.0, offset], m.F)


@st.composite
def curves(draw, mesh: igljoin.Mesh):
    loop = igljoin.boundary_loops(mesh.F)[0]
    kind = draw(st.sampled_from(["closed", "start", "open", "via", "point", "indices"]))
    a = int(draw(st.sampled_from(loop.tolist())))
    b = int(draw(st.sampled_from(loop.tolist())))
    if kind == "closed":
        return None
    if kind == "start":
        return igljoin.Curve(start=a)
    if kind == "open":
        return igljoin.Curve(start=a, end=b)
    if kind == "via":
        c = int(draw(st.sampled_from(loop.tolist())))
        return igljoin.Curve(start=a, end=b, via=c)
    if kind == "point":
        return igljoin.Curve(start=mesh.V[a] + draw(st.floats(-0.1, 0.1)))
    k = draw(st.integers(1, len(loop)))
    s = draw(st.integers(0, len(loop) - 1))
    return np.roll(loop, -s)[:k]


options = st.fixed_dictionaries(
    {},
    optional={
        "smooth": st.booleans(),
        "shape_weight": st.floats(0.0, 5.0),
        "stretch_weight": st.floats(0.0, 5.0),
        "smooth_weight": st.floats(0.0, 50.0),
        "smooth_mode": st.sampled_from(["robust", "paper"]),
        "laplacian": st.sampled_from(["uniform", "cotangent"]),
        "rotation_aware": st.booleans(),
        "max_iterations": st.integers(1, 60),
        "acceleration": st.integers(0, 8),
        "snap_fraction": st.floats(0.0, 0.49),
    },
)


def _check(res: igljoin.JoinResult) -> None:
    assert np.isfinite(res.guest.V).all()
    assert np.isfinite(res.area_ratio).all()
    assert np.isfinite(res.energy).all()


def _join_checked(*args, **kw) -> None:
    """Join; only documented errors, a finite result, and within the time bound either way."""
    t0 = time.perf_counter()
    try:
        res = igljoin.join(*args, **kw)
    except igljoin.IgljoinError as exc:
        event(f"rejected: {type(exc).__name__}")
        res = None
    assert time.perf_counter() - t0 < CALL_BOUND
    if res is not None:
        event("joined")
        _check(res)


@given(data=st.data())
def test_random_valid_joins(data):
    EXAMPLES_RUN["test_random_valid_joins"] += 1
    host = data.draw(sheets())
    guest = data.draw(sheets(offset=2.0))
    hc = data.draw(curves(host))
    gc = data.draw(curves(guest))
    opts = data.draw(options)
    _join_checked(host, guest, hc, gc, **opts)


@given(
    V=st.lists(
        st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), min_size=3, max_size=3),
        min_size=0,
        max_size=12,
    ),
    F=st.lists(st.lists(st.integers(-2, 14), min_size=3, max_size=3), min_size=0, max_size=16),
    curve=st.one_of(st.none(), st.integers(-1, 3), st.lists(st.integers(-1, 14), max_size=6)),
)
def test_random_corrupt_meshes_only_raise_documented_errors(V, F, curve):
    EXAMPLES_RUN["test_random_corrupt_meshes_only_raise_documented_errors"] += 1
    host = grid(4, 4, np.zeros(16), np.zeros((16, 2)))
    _join_checked(host, (np.array(V, dtype=float).reshape(-1, 3), F), None, curve)


@given(
    opts=st.dictionaries(
        st.sampled_from(
            [
                "shape_weight",
                "stretch_weight",
                "smooth_weight",
                "energy_tolerance",
                "max_iterations",
                "snap_fraction",
                "smooth_radius",
                "acceleration",
                "time_limit",
                "smooth_keep_deg",
                "smooth",
            ]
        ),
        st.one_of(
            st.floats(allow_nan=True, allow_infinity=True),
            st.integers(-5, 5),
            st.booleans(),
            st.text(max_size=3),
            st.none(),
        ),
        max_size=3,
    )
)
def test_random_option_values_only_raise_options_errors(opts):
    EXAMPLES_RUN["test_random_option_values_only_raise_options_errors"] += 1
    try:
        igljoin.JoinOptions.make(**opts)
    except igljoin.OptionsError:
        pass


def test_ci_profile_runs_at_least_2000_examples():
    """The issue asks for >= 2,000 fuzz examples in make test: the three tests above ran them.

    Counts what the three tests executed in this session (pytest runs a module's
    tests in file order, so they ran before this one).
    """
    budget = (
        "test_random_valid_joins",
        "test_random_corrupt_meshes_only_raise_documented_errors",
        "test_random_option_values_only_raise_options_errors",
    )
    missing = [name for name in budget if not EXAMPLES_RUN[name]]
    if missing:
        pytest.skip(f"counts the examples of {', '.join(missing)}: run the whole module")
    assert sum(EXAMPLES_RUN[name] for name in budget) >= 2000, dict(EXAMPLES_RUN)


def _edge_manifold(F: np.ndarray) -> bool:
    edges = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    _, count = np.unique(edges, axis=0, return_counts=True)
    return bool((count <= 2).all())


def test_random_joins_weld_cleanly():
    """A join that succeeds welds into a finite, edge-manifold mesh whose seam vertices
    join host and guest faces, or the weld refuses it with a WeldError; and some do weld."""
    outcomes: collections.Counter = collections.Counter()

    @given(data=st.data())
    @settings(max_examples=60)
    def one(data):
        host = data.draw(sheets())
        guest = data.draw(sheets(offset=2.0))
        try:
            res = igljoin.join(host, guest)
        except igljoin.IgljoinError:
            outcomes["join refused"] += 1
            return
        try:
            welded = res.weld()
        except igljoin.WeldError:  # a documented refusal (zero-area or 3-face seam edges)
            outcomes["weld refused"] += 1
            return
        M = welded.mesh
        assert np.isfinite(M.V).all()
        assert _edge_manifold(M.F)
        for label in (0, 1):  # every seam vertex is a corner of a host and of a guest face
            corners = np.zeros(len(M.V), dtype=bool)
            corners[M.F[welded.label == label].ravel()] = True
            assert corners[welded.seam].all()
        outcomes["welded"] += 1

    one()
    # about a third of these random sheets weld (22 of 60 when measured); a tenth
    # of the examples is far below that and still proves the welded path runs
    assert outcomes["welded"] >= 6, dict(outcomes)


# --------------------------------------------------------------------------- hostile inputs
# The input classes of the "nothing lost, nothing faked" review: mesh-file tokens, spec
# values of extreme size and type, and file-system oddities. Each may only raise
# igljoin's documented errors (or OSError for the file system), never hang or crash.

#: Examples per hostile-input test in the ci profile (each writes files: ~5 ms each).
HOSTILE_EXAMPLES = max(50, settings.default.max_examples // 7)

_huge_ints = st.one_of(
    st.integers(-(10**400), 10**400), st.integers(2**31 - 2, 2**63 + 2), st.integers(-3, 3)
)
_odd_floats = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([1e308, -1e308, 5e-324])
)
_odd_strings = st.text(
    alphabet=st.characters(min_codepoint=0, max_codepoint=0x2FF), max_size=12
) | st.sampled_from(["robust", "../host.ply", "host.ply\x00", "", "k.npy"])


def _toml(value, depth: int = 0) -> str:
    """TOML text of a Python value (ints of any size, floats incl. nan/inf, nested arrays)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if value != value:
            return "nan"
        if value in (float("inf"), float("-inf")):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return (
            '"'
            + "".join(c if c.isalnum() or c in "._-/ " else f"\\u{ord(c):04x}" for c in value)
            + '"'
        )
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v, depth + 1) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {_toml(v, depth + 1)}" for k, v in value.items()) + "}"
    raise TypeError(value)


_spec_values = st.recursive(
    st.one_of(_huge_ints, _odd_floats, _odd_strings, st.booleans()),
    lambda inner: (
        st.lists(inner, max_size=4)
        | st.dictionaries(st.sampled_from(["enabled", "target_edge", "iterations", "loop"]), inner)
    ),
    max_leaves=8,
)
_spec_keys = st.sampled_from(
    [
        ("options", "shape_weight"),
        ("options", "smooth_weight"),
        ("options", "max_iterations"),
        ("options", "time_limit"),
        ("options", "smooth_mode"),
        ("options", "stiffness"),
        ("options", "resample"),
        ("options", "cleanup"),
        ("host_curve", "loop"),
        ("host_curve", "start"),
        ("host_curve", "indices"),
        ("guest_curve", "via"),
        (None, "host"),
        (None, "description"),
    ]
)


def _patch_files(folder) -> None:
    host = grid(5, 5, np.zeros(25), np.zeros((25, 2)))
    guest = grid(4, 4, np.zeros(16), np.zeros((16, 2)))
    igljoin.write_mesh(folder / "host.ply", host)
    igljoin.write_mesh(folder / "guest.ply", guest)


@given(entries=st.lists(st.tuples(_spec_keys, _spec_values), min_size=1, max_size=3))
@settings(max_examples=HOSTILE_EXAMPLES)
def test_random_spec_values_only_raise_spec_errors(entries):
    import tempfile
    from pathlib import Path

    tables: dict = {}
    for (table, key), value in entries:
        tables.setdefault(table, {})[key] = value
    lines = [f"{k} = {_toml(v)}" for k, v in tables.pop(None, {}).items()]
    for table, values in tables.items():
        lines.append(f"[{table}]")
        lines += [f"{k} = {_toml(v)}" for k, v in values.items()]
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "case"
        folder.mkdir()
        _patch_files(folder)
        (folder / "join.toml").write_text("\n".join(lines) + "\n", encoding="utf-8")
        t0 = time.perf_counter()
        try:
            igljoin.load_case(folder)
            event("accepted")
        except igljoin.SpecError:
            event("rejected: SpecError")
        assert time.perf_counter() - t0 < CALL_BOUND


@given(
    opts=st.dictionaries(
        st.sampled_from(
            [
                "shape_weight",
                "smooth_weight",
                "time_limit",
                "max_iterations",
                "smooth_mode",
                "laplacian",
                "acceleration",
                "stiffness",
                "energy_tolerance",
            ]
        ),
        st.one_of(
            _huge_ints,
            _odd_floats,
            st.builds(lambda n: np.array(["robust"] * n), st.integers(0, 3)),
            st.builds(np.float32, st.floats(width=32)),
            st.builds(np.int64, st.integers(-(2**63), 2**63 - 1)),
        ),
        max_size=3,
    )
)
@settings(max_examples=HOSTILE_EXAMPLES)
def test_extreme_api_option_values_only_raise_options_errors(opts):
    try:
        igljoin.JoinOptions.make(**opts)
        event("accepted")
    except igljoin.OptionsError:
        event("rejected: OptionsError")


_tokens = st.one_of(
    _huge_ints.map(str),
    _odd_floats.map(repr),
    st.sampled_from(["nan", "inf", "-0", "1e400", "0x10", "//", "#", "", "3/4/5", "\x00", "é"]),
)


@given(
    kind=st.sampled_from(["obj", "off"]),
    lines=st.lists(
        st.tuples(st.sampled_from(["v", "f", "vn", "OFF", "", "#"]), st.lists(_tokens, max_size=5)),
        max_size=12,
    ),
)
@settings(max_examples=HOSTILE_EXAMPLES)
def test_hostile_mesh_file_tokens_only_raise_read_errors(kind, lines):
    import tempfile
    from pathlib import Path

    text = "\n".join(" ".join([head, *toks]) for head, toks in lines) + "\n"
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"m.{kind}"
        path.write_text(text, encoding="utf-8")
        t0 = time.perf_counter()
        try:
            igljoin.read_mesh(path)
            event("read")
        except igljoin.IgljoinError as exc:
            event(f"rejected: {type(exc).__name__}")
        assert time.perf_counter() - t0 < CALL_BOUND


_odd_entries = st.sampled_from(
    ["regular", "self-loop", "dangling", "directory", "fifo", "empty", "outside"]
)


@given(host=_odd_entries, spec=_odd_entries)
@settings(max_examples=HOSTILE_EXAMPLES)
def test_filesystem_oddities_in_a_case_folder_only_raise_spec_errors(host, spec):
    import os
    import tempfile
    from pathlib import Path

    def make(path: Path, how: str, content: bytes) -> None:
        path.unlink(missing_ok=True)
        if how == "regular":
            path.write_bytes(content)
        elif how == "self-loop":
            os.symlink(path.name, path)
        elif how == "dangling":
            os.symlink("nowhere", path)
        elif how == "directory":
            path.mkdir()
        elif how == "fifo":
            os.mkfifo(path)  # opening it to read would block: it must never be opened
        elif how == "empty":
            path.write_bytes(b"")
        else:
            os.symlink("/etc/hostname", path)

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "case"
        folder.mkdir()
        _patch_files(folder)
        make(folder / "host.ply", host, (folder / "host.ply").read_bytes())
        make(folder / "join.toml", spec, b"[host_curve]\nloop = 0\n")
        try:
            spec_ = igljoin.load_case(folder)
            spec_.input_hashes()
            event("accepted")
        except igljoin.SpecError:
            event("rejected: SpecError")
