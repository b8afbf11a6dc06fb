"""Output folders: igljoin never deletes or replaces what it did not write (the CLI).

The command line runs in this process (``igljoin.cli.main``, see ``cli_run``):
what is checked is the files left in the folders and the exit code and
messages ``main`` gives, none of which needs a process of its own.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
from pathlib import Path

import pytest

import igljoin
from igljoin import phantoms
from igljoin.errors import OutputError
from igljoin.outputs import MANIFEST, read_manifest
from igljoin.pipeline import run_case

from .cli_run import call

JOIN_FILES = ["guest.ply", "guest.vtu", "merged.ply", "merged.vtu", "report.json", "timings.json"]


def cli(*args) -> subprocess.CompletedProcess:
    return call(*args)


def tree(root: Path) -> dict[str, str]:
    """Every file under ``root`` -> SHA-256, and every folder -> "dir"."""
    out = {}
    for p in sorted(root.rglob("*")):
        rel = str(p.relative_to(root))
        out[rel] = "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def user_files(root: Path) -> None:
    """What a user may keep in a folder: files, a sub-folder, names like igljoin's temporaries."""
    (root / "demo" / "end_to_end").mkdir(parents=True)
    (root / "demo" / "end_to_end" / "table.md").write_text("| my | table |\n")
    (root / "notes.txt").write_bytes(b"my notes\x00\xff")
    (root / ".case.tmp-deadbeef").mkdir()  # a user folder that merely looks like a temporary
    (root / ".case.tmp-deadbeef" / "keep.txt").write_text("mine")
    (root / ".guest.tmp-deadbeef.ply").write_text("not igljoin's")


@pytest.fixture(scope="module")
def case(tmp_path_factory) -> Path:
    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.3)
    root = tmp_path_factory.mktemp("case") / "patch"
    root.mkdir()
    igljoin.write_mesh(root / "host.ply", s.host)
    igljoin.write_mesh(root / "guest.ply", s.guest)
    (root / "join.toml").write_text("[host_curve]\nloop = 0\n")
    return root


def test_join_into_a_folder_of_user_files_keeps_them_byte_for_byte(case, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    user_files(out)
    before = tree(out)
    for _ in range(2):  # the second run replaces igljoin's own files, and only those
        proc = cli("join", case / "host.ply", case / "guest.ply", "-o", out, "--host-loop", "0")
        assert proc.returncode == 0, proc.stderr
        after = tree(out)
        assert {k: after[k] for k in before} == before
        assert sorted(set(after) - set(before)) == sorted([MANIFEST, *JOIN_FILES])
    assert sorted(read_manifest(out)) == JOIN_FILES
    assert f"wrote {', '.join(JOIN_FILES)}" in proc.stdout  # only igljoin's files are named


def test_join_refuses_a_file_as_output_folder(case, tmp_path):
    notes = tmp_path / "notes.txt"
    notes.write_text("precious")
    proc = cli("join", case / "host.ply", case / "guest.ply", "-o", notes, "--host-loop", "0")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert "is an existing file, not a folder" in proc.stderr and "choose a folder" in proc.stderr
    assert notes.read_text() == "precious" and sorted(p.name for p in tmp_path.iterdir()) == [
        "notes.txt"
    ]


def test_join_refuses_to_replace_a_foreign_file_of_an_output_name(case, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "report.json").write_text('{"mine": true}')
    with pytest.raises(OutputError, match="already holds 'report.json', which igljoin did not"):
        run_case(case, out, record_errors=False)
    assert sorted(p.name for p in out.iterdir()) == ["report.json"]
    assert (out / "report.json").read_text() == '{"mine": true}'
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no staging folder left


def test_a_failure_after_a_success_removes_only_igljoin_files(case, tmp_path):
    out = tmp_path / "one"
    assert run_case(case, out)["status"] == "ok"
    (out / "my-notes.txt").write_text("keep me")
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "host.ply").write_bytes((case / "host.ply").read_bytes())
    (bad / "guest.ply").write_text("not a mesh")
    (bad / "join.toml").write_text("")
    row = run_case(bad, out)
    assert row["status"] == "failed" and row["step"] == "read"
    names = sorted(p.name for p in out.iterdir())
    assert names == [MANIFEST, "error.json", "my-notes.txt", "timings.json"]
    assert (out / "my-notes.txt").read_text() == "keep me"


def test_batch_keeps_user_files_and_look_alike_temporaries(case, tmp_path):
    cases = tmp_path / "cases"
    cases.mkdir()
    for name in ("a", "b"):
        (cases / name).mkdir()
        for f in case.iterdir():
            (cases / name / f.name).write_bytes(f.read_bytes())
    out = tmp_path / "out"
    out.mkdir()
    user_files(out)
    (out / "a").mkdir()
    (out / "a" / "mine.csv").write_text("1,2\n")
    before = tree(out)
    for flags in ([], ["--resume"]):
        proc = cli("batch", cases, "-o", out, "--workers", "0", "--no-progress", *flags)
        assert proc.returncode == 0, proc.stderr
        after = tree(out)
        assert {k: after[k] for k in before} == before
    assert json.loads((out / "summary.json").read_text())["ok"] == 2
    assert sorted(read_manifest(out)) == ["summary.csv", "summary.json"]


def test_batch_refuses_a_foreign_summary_and_a_file_as_folder(case, tmp_path):
    cases = tmp_path / "cases"
    (cases / "a").mkdir(parents=True)
    for f in case.iterdir():
        (cases / "a" / f.name).write_bytes(f.read_bytes())
    out = tmp_path / "out"
    out.mkdir()
    (out / "summary.csv").write_text("my,own\n")
    proc = cli("batch", cases, "-o", out, "--workers", "0")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert "already holds 'summary.csv', which igljoin did not write" in proc.stderr
    assert sorted(p.name for p in out.iterdir()) == ["summary.csv"]  # refused before any case
    proc = cli("batch", cases, "-o", out / "summary.csv", "--workers", "0")
    assert proc.returncode == 1 and "is an existing file, not a folder" in proc.stderr
    assert (out / "summary.csv").read_text() == "my,own\n"
