"""The ``igljoin`` command line.

Argument handling and output are tested in this process through
``igljoin.cli.main(argv)`` (:func:`tests.cli_run.call`); what needs a real
process — the exit status the system sees, a terminal — runs the console
script (:func:`tests.cli_run.spawn`).
"""

from __future__ import annotations

import importlib.util
import json
import re
import subprocess
from pathlib import Path

import pytest

import igljoin
from igljoin import phantoms

from .cli_run import IGLJOIN, spawn
from .cli_run import call as run
from .cuts import sample_mesh_dir
from .test_clean import corrupt

COMMANDS = ("join", "batch", "clean", "info", "demo", "render", "inspect")


def assert_one_line_error(proc: subprocess.CompletedProcess, code: int, text: str) -> None:
    assert proc.returncode == code, proc.stderr
    assert "Traceback" not in proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert text in last, last
    if code == 1:  # library errors: exactly one line, no usage block
        assert proc.stderr.strip().count("\n") == 0 and last.startswith("igljoin: error: ")


@pytest.fixture(scope="module")
def patch_files(tmp_path_factory) -> tuple[Path, Path]:
    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.4)
    root = tmp_path_factory.mktemp("files")
    return (
        igljoin.write_mesh(root / "host.ply", s.host),
        igljoin.write_mesh(root / "guest.obj", s.guest),
    )


# --------------------------------------------------------------------------- help


def test_top_level_help_lists_every_command():
    proc = run("--help")
    assert proc.returncode == 0
    for command in COMMANDS:
        assert f"\n    {command} " in proc.stdout
    assert "examples:" in proc.stdout
    assert run("--version").stdout.strip() == f"igljoin {igljoin.__version__}"


@pytest.mark.parametrize(
    "command, expected",
    [
        ("join", ["HOST GUEST", "--host-loop K", "--guest-start V", "--no-smooth", "--option"]),
        ("batch", ["CASES", "--workers N", "--scheduler ADDRESS", "--dask-local N", "--resume"]),
        ("clean", ["IN", "--close-holes", "--keep-loop K", "--resample EDGE"]),
        ("info", ["MESH", "--json"]),
        ("demo", ["--out DIR", "out/demo"]),
        ("render", ["CASE | HOST GUEST", "--view {side,along,both}"]),
        ("inspect", ["CASE | HOST GUEST", "--host-loop K"]),
    ],
)
def test_subcommand_help(command, expected):
    proc = run(command, "--help")
    assert proc.returncode == 0
    assert proc.stdout.startswith(f"usage: igljoin {command} ")
    for text in expected:
        assert text in proc.stdout
    assert max(len(line) for line in proc.stdout.splitlines()) <= 100  # wrapped


def test_console_script_exit_status():
    """The process exits with what main() returns: 0, 1 for a failure, 2 for usage."""
    proc = spawn("--version")
    assert proc.returncode == 0 and proc.stdout.strip() == f"igljoin {igljoin.__version__}"
    proc = spawn()
    assert proc.returncode == 2 and "usage: igljoin" in proc.stderr
    assert_one_line_error(spawn("frobnicate"), 2, "invalid choice: 'frobnicate'")
    assert_one_line_error(spawn("info", "no-such-mesh.ply"), 1, "mesh file not found")


def test_usage_errors_exit_2():
    proc = run()
    assert proc.returncode == 2 and "usage: igljoin" in proc.stderr
    assert_one_line_error(run("frobnicate"), 2, "invalid choice: 'frobnicate'")
    assert_one_line_error(run("join", "a.ply"), 2, "the following arguments are required")
    assert_one_line_error(
        run("join", "a.ply", "b.ply", "-o", "x", "--host-start", "1,2"),
        2,
        "'1,2' is neither a vertex index",
    )
    assert_one_line_error(
        run("batch", "c", "-o", "x", "--workers", "2", "--dask-local", "2"),
        2,
        "not allowed with argument",
    )


# --------------------------------------------------------------------------- info


def test_info_on_a_real_scan():
    scan = sample_mesh_dir() / "bunny10k_textured.obj"
    proc = run("info", scan)
    assert proc.returncode == 0
    assert "5051 vertices, 9999 faces" in proc.stdout
    assert "boundary loops: 5" in proc.stdout and "loop 0: 38 vertices" in proc.stdout
    assert "sliver faces: 1" in proc.stdout
    doc = json.loads(run("info", scan, "--json").stdout)
    assert [lp["size"] for lp in doc["loops"]] == [38, 22, 22, 19, 8]
    assert doc["components"] == 1 and doc["problems"]["sliver_faces"] == 1


def test_info_lists_the_problems_of_a_broken_mesh(tmp_path):
    bad = corrupt(igljoin.read_mesh(sample_mesh_dir() / "bunny10k_textured.obj"))
    path = igljoin.write_mesh(tmp_path / "broken.ply", bad)
    proc = run("info", path)
    assert proc.returncode == 0
    for line in (
        "degenerate faces: 1",
        "duplicate faces: 2",
        "non manifold edges: 1",
        "non manifold vertices: 1",
        "unreferenced vertices: 5",
        "duplicate vertices: 3",
        "loops are not defined while edges are non-manifold",
    ):
        assert line in proc.stdout


# --------------------------------------------------------------------------- join


def test_join_files(patch_files, tmp_path):
    host, guest = patch_files
    out = tmp_path / "joined"
    proc = run("join", host, guest, "-o", out, "--host-loop", "0")
    assert proc.returncode == 0, proc.stderr
    assert "converged: True" in proc.stdout and "crease mean" in proc.stdout
    assert sorted(p.name for p in out.iterdir()) == [
        ".igljoin-manifest.json",  # the list of igljoin's own files (docs/pipelines.md)
        "guest.ply",
        "guest.vtu",
        "merged.ply",
        "merged.vtu",
        "report.json",
        "timings.json",
    ]
    flags = "--host-start 0 --no-smooth -O smooth_weight=5 -O smooth_mode=paper --json"
    proc = run("join", host, guest, "-o", tmp_path / "j2", *flags.split())
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    assert doc["summary"]["status"] == "ok" and doc["summary"]["converged"] is True
    report = json.loads((tmp_path / "j2" / "report.json").read_text())
    assert report["options"]["smooth"] is False and report["options"]["smooth_mode"] == "paper"
    assert report["spec"]["host_curve"] == {"start": 0}


def test_join_takes_an_old_option_name_with_a_warning(patch_files, tmp_path):
    host, guest = patch_files
    flags = "--host-loop 0 -O tolerance=1e-3 -O max_iterations=5"
    with pytest.warns(DeprecationWarning, match="tolerance is now called energy_tolerance"):
        proc = run("join", host, guest, "-o", tmp_path / "old", *flags.split())
    assert proc.returncode == 0, proc.stderr
    report = json.loads((tmp_path / "old" / "report.json").read_text())
    assert report["options"]["energy_tolerance"] == 1e-3 and "tolerance" not in report["options"]
    both = flags + " -O energy_tolerance=1e-3"
    proc = run("join", host, guest, "-o", tmp_path / "both", *both.split())
    assert_one_line_error(proc, 2, "tolerance and energy_tolerance are the same option")


def test_join_status_line_draws_and_erases(patch_files):
    import io

    from igljoin.cli import SolveStatus

    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.5)
    stream = io.StringIO()
    status = SolveStatus(stream, delay=0.0, interval=0.0)
    res = igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve, progress=status)
    drawn = stream.getvalue().split("\r")[1:]
    # one draw per iteration (no delay, no throttle), each naming its iteration
    assert len(drawn) == res.iterations
    numbers = range(1, res.iterations + 1)
    assert all(f"iteration {k} (at most 2000)" in d for k, d in zip(numbers, drawn))
    status.close()
    erased = stream.getvalue().split("\r")
    assert erased[-1] == "" and erased[-2].strip() == ""  # the line is blanked, cursor home
    # a quick join under the default one-second delay draws nothing
    quiet = io.StringIO()
    igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve, progress=SolveStatus(quiet))
    assert quiet.getvalue() == ""
    # a line drawn before the solve is replaced by the first iteration, then throttled
    started = io.StringIO()
    status = SolveStatus(started, interval=3600.0)
    status.begin("preparing")
    igljoin.join(s.host, s.guest, s.host_curve, s.guest_curve, progress=status)
    lines = started.getvalue().split("\r")[1:]
    assert lines[0] == "preparing" and len(lines) == 2 and "iteration 1 (" in lines[1]
    # the shorter text is padded to blank the longer one it overwrites
    assert len(lines[1]) >= len("preparing")


def _run_on_a_terminal(*args) -> tuple[subprocess.CompletedProcess, bytes]:
    """Run the CLI with stderr on a pseudo-terminal; returns the process and what it drew."""
    import os
    import pty

    leader, follower = pty.openpty()
    command = [str(IGLJOIN), *map(str, args)]
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=follower)
    os.close(follower)
    drawn = b""
    while True:
        try:
            chunk = os.read(leader, 4096)
        except OSError:  # the terminal closes when the process ends
            break
        if not chunk:
            break
        drawn += chunk
    stdout = proc.stdout.read()
    proc.wait(timeout=300)
    os.close(leader)
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, b""), drawn


def test_join_status_line_on_a_terminal(tmp_path):
    s = phantoms.paper_sample("end_to_end", "equal")
    igljoin.write_mesh(tmp_path / "host.ply", s.host)
    igljoin.write_mesh(tmp_path / "guest.ply", s.guest)
    # the plain iteration to a tolerance it cannot reach: 3,000 iterations, over a second
    flags = "-O acceleration=0 -O energy_tolerance=1e-14 -O max_iterations=3000"
    proc, drawn = _run_on_a_terminal(
        "join", tmp_path / "host.ply", tmp_path / "guest.ply", "-o", tmp_path / "out",
        "--host-start", "0", "--guest-loop", "0", *flags.split(),
    )  # fmt: skip
    assert proc.returncode == 0 and b"joined" in proc.stdout
    lines = drawn.split(b"\r")
    assert lines[1] == b"igljoin: reading, checking and factoring (large guests take a while)"
    assert b"igljoin: joining, iteration 1 (at most 3000)" in lines[2]
    # redrawn as the iteration advances (at most every 0.2 s)
    shown = [int(m.group(1)) for m in map(re.compile(rb"iteration (\d+) ").search, lines) if m]
    assert len(shown) >= 2 and shown == sorted(shown) and shown[-1] > shown[0]
    # the status line is blanked at the end and nothing else is written to stderr
    assert lines[-1] == b"" and lines[-2].strip() == b""
    assert b"Traceback" not in drawn


def test_join_shows_no_status_line_off_a_terminal(patch_files, tmp_path):
    host, guest = patch_files
    proc = spawn("join", host, guest, "-o", tmp_path / "j", "--host-loop", "0")
    assert proc.returncode == 0 and "joining, iteration" not in proc.stderr


def test_join_with_cleanup_and_resample(tmp_path):
    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.4, guest_resolution=0.2)
    host = igljoin.write_mesh(tmp_path / "host.ply", s.host)
    guest = igljoin.write_mesh(tmp_path / "guest.off", s.guest)
    flags = "--host-loop 0 --cleanup --resample --json".split()
    proc = run("join", host, guest, "-o", tmp_path / "o", *flags)
    assert proc.returncode == 0, proc.stderr
    report = json.loads((tmp_path / "o" / "report.json").read_text())
    assert report["cleanup"]["guest"]["total"] == 0  # the phantom is clean
    assert report["resample"]["after"]["vertices"] > 10 * s.guest.n_vertices
    flags = "--host-loop 0 --resample --guest-start 0".split()
    proc = run("join", host, guest, "-o", tmp_path / "o2", *flags)
    assert_one_line_error(proc, 2, "give the guest curve by loop index or by points")


def test_join_errors_are_one_line_and_leave_out_alone(patch_files, tmp_path):
    host, guest = patch_files
    assert_one_line_error(
        run("join", tmp_path / "nope.ply", guest, "-o", tmp_path / "o"), 1, "mesh file not found"
    )
    out = tmp_path / "o"
    proc = run("join", host, guest, "-o", out, "--host-loop", "7")
    assert_one_line_error(proc, 1, "host_curve: loop 7 does not exist")
    proc = run("join", host, guest, "-o", out)
    assert_one_line_error(proc, 1, "say which to join")
    assert not out.exists() and list(tmp_path.iterdir()) == []  # no partial output
    proc = run("join", host, guest, "-o", out, "-O", "smoth=1")
    assert_one_line_error(proc, 2, "unknown options 'smoth'; valid keys are smooth")


# --------------------------------------------------------------------------- clean


def test_clean_a_broken_file(tmp_path):
    bad = corrupt(igljoin.read_mesh(sample_mesh_dir() / "bunny10k_textured.obj"))
    src = igljoin.write_mesh(tmp_path / "broken.ply", bad)
    before = src.read_bytes()
    out = tmp_path / "fixed.ply"
    proc = run("clean", src, "-o", out, "--close-holes", "--keep-loop", "0", "--json")
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    assert doc["clean"]["fixes"]["duplicate_vertices"] == 3 and doc["clean"]["after"]["ok"]
    assert src.read_bytes() == before  # the input is never touched
    info = json.loads(run("info", out, "--json").stdout)
    assert info["ok"] and [lp["size"] for lp in info["loops"]] == [38]
    proc = run("clean", src, "-o", tmp_path / "f2.ply")
    assert proc.returncode == 0 and "duplicate faces: 2" in proc.stdout
    assert_one_line_error(run("clean", src, "-o", src), 2, "is the input file")
    garbage = tmp_path / "garbage.obj"
    garbage.write_text("v 1 2\n")
    assert_one_line_error(run("clean", garbage, "-o", tmp_path / "g.ply"), 1, "garbage.obj")


# --------------------------------------------------------------------------- batch, demo, viz


def test_batch_on_a_folder_without_cases(tmp_path):
    assert_one_line_error(run("batch", tmp_path, "-o", tmp_path / "o"), 1, "no case folders")


def test_demo_writes_the_paper_table(tmp_path):
    out = tmp_path / "demo"
    proc = run("demo", "--out", out, "--resolution", "0.3", "--no-progress", "--json")
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    assert Path(doc["paths"]["table_md"]).is_file() and doc["claims"]


@pytest.mark.skipif(importlib.util.find_spec("polyscope") is None, reason="viz extra")
def test_render_a_case_folder(patch_files, tmp_path):
    host, guest = patch_files
    case = tmp_path / "case"
    case.mkdir()
    for f in (host, guest):
        (case / f.name).write_bytes(f.read_bytes())
    (case / "join.toml").write_text("[host_curve]\nloop = 0\n")
    png = tmp_path / "picture.png"
    proc = run("render", case, "-o", png, "--view", "both")
    assert proc.returncode == 0, proc.stderr
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert_one_line_error(run("render", host, "-o", png), 2, "give a case folder")
