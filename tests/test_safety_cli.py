"""What once hung or printed a traceback: now bounded and one line (real processes)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import igljoin
from igljoin import phantoms
from igljoin.cli import main
from igljoin.pipeline import run_batch

from .cuts import sample_mesh_dir

IGLJOIN = Path(sys.executable).parent / "igljoin"


def cli(*args, env=None, timeout=120) -> subprocess.CompletedProcess:
    # the timeout is the hang bound: each of these once ran for minutes or forever
    return subprocess.run(
        [str(IGLJOIN), *map(str, args)], capture_output=True, text=True, timeout=timeout, env=env
    )


@pytest.fixture(scope="module")
def patch_files(tmp_path_factory):
    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.3)
    root = tmp_path_factory.mktemp("files")
    return igljoin.write_mesh(root / "host.ply", s.host), igljoin.write_mesh(
        root / "guest.ply", s.guest
    )


def test_inspect_without_a_display_says_to_render_before_joining(patch_files, tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    # a host curve that does not exist: had inspect joined first, this error would show instead
    proc = cli("inspect", *patch_files, "--host-loop", "7", env=env)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert "no display" in last and "igljoin render" in last and "loop 7" not in last


def test_a_closed_pipe_ends_quietly(patch_files):
    proc = subprocess.Popen(
        [str(IGLJOIN), "info", "--json", str(patch_files[0])],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    proc.stdout.close()  # the reader is gone before a byte is written (like `| head -0`)
    err = proc.stderr.read().decode()
    proc.wait(timeout=120)
    assert err == ""
    assert proc.returncode == 141  # 128 + SIGPIPE: what a shell reports for `... | head`


def test_clean_resample_to_a_tiny_edge_is_refused_at_once(tmp_path, capsys):
    # in-process main(argv): the guard, not the process, is what is tested; a hang here
    # (the 42 s and 5.7 GB) would stop the suite's time bound
    code = main(
        [
            "clean",
            str(sample_mesh_dir() / "bunny10k_textured.obj"),
            "-o",
            str(tmp_path / "b.ply"),
            "--resample",
            "0.0001",
        ]
    )
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1 and err.startswith("igljoin: error: ")
    assert "faces, more than the 2,000,000 allowed" in err
    assert not (tmp_path / "b.ply").exists()


def test_many_loops_give_a_bounded_message():
    x, y = np.meshgrid(np.arange(121.0), np.arange(121.0))
    V = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    i = (np.arange(120)[None, :] + 121 * np.arange(120)[:, None]).ravel()
    F = np.concatenate([np.stack([i, i + 1, i + 122], 1), np.stack([i, i + 122, i + 121], 1)])
    keep = np.ones(len(F), dtype=bool)
    cells = np.arange(120 * 120).reshape(120, 120)[1:-1:3, 1:-1:3].ravel()
    keep[cells] = False  # 1,600 isolated triangular holes
    host = igljoin.Mesh(V, F[keep])
    with pytest.raises(igljoin.CurveError) as info:
        igljoin.select_curve(host, None, name="host_curve")
    msg = str(info.value)
    assert "1,601 boundary loops" in msg and "... and 1,591 more" in msg
    assert len(msg) < 500  # was 118,942 characters for 39,602 loops


def test_resume_over_a_fifo_a_deep_report_and_a_symlink_loop(patch_files, tmp_path, capsys):
    cases = tmp_path / "cases"
    for name in ("a", "b", "c"):
        (cases / name).mkdir(parents=True)
        for f in patch_files:
            (cases / name / f.name).write_bytes(f.read_bytes())
        (cases / name / "join.toml").write_text("[host_curve]\nloop = 0\n")
    out = tmp_path / "out"
    assert run_batch(cases, out, workers=0, progress=False).ok
    (out / "a" / "report.json").unlink()
    os.mkfifo(out / "a" / "report.json")  # opening it to read would block forever
    (out / "b" / "report.json").write_text("[" * 100_000 + "]" * 100_000)  # RecursionError
    (cases / "c" / "host.ply").unlink()
    os.symlink("host.ply", cases / "c" / "host.ply")  # a loop
    code = main(["batch", str(cases), "-o", str(out), "--resume", "--workers", "0", "--json"])
    assert code == 1  # nothing hangs or dies; the summary is written
    doc = json.loads(capsys.readouterr().out)
    assert doc["ran"] == ["a", "b", "c"] and doc["failed_cases"] == ["a", "c"]
    a, b, c = doc["rows"]
    # the FIFO is not igljoin's to replace: case a fails with the reason, without blocking
    assert (
        a["step"] == "output"
        and "special file (e.g. a FIFO) named 'report.json'" in (a["error_message"])
    )
    assert (out / "a" / "report.json").is_fifo()
    assert (
        b["status"] == "ok" and json.loads((out / "b" / "report.json").read_text())["case"] == "b"
    )
    assert "symbolic link that loops" in c["error_message"]
    assert json.loads((out / "summary.json").read_text())["failed_cases"] == ["a", "c"]
