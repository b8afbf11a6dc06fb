"""``import igljoin`` loads nothing heavy; each name imports its submodule on first use.

Each check runs in a fresh interpreter (what is imported depends on what the
process imported before). The wall times are measured by
``pipelines/startup_benchmark.py``, not here.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import igljoin

ROOT = Path(__file__).resolve().parents[1]

#: Packages that cost start-up time (tenths of a second to seconds each).
HEAVY = (
    "numpy", "scipy", "scipy.spatial", "igl", "numba", "plyfile", "pymeshlab", "polyscope",
    "PIL", "dask",
)  # fmt: skip


def _loaded_after(code: str) -> dict:
    """Run ``code`` in a fresh interpreter; which HEAVY packages it imported, and its output."""
    probe = textwrap.dedent(code) + textwrap.dedent(
        f"""
        import json, sys
        print(json.dumps({{"loaded": sorted(m for m in {HEAVY!r} if m in sys.modules)}}))
        """
    )
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, env=env, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_import_igljoin_and_the_parser_load_nothing_heavy():
    got = _loaded_after(
        """
        import contextlib, io
        import igljoin
        from igljoin.cli import main
        with contextlib.redirect_stdout(io.StringIO()):
            try:
                main(["--version"])
            except SystemExit:
                pass
            for command in ("join", "batch", "clean", "info", "demo", "render", "inspect"):
                try:
                    main([command, "--help"])
                except SystemExit:
                    pass
        """
    )
    assert got["loaded"] == []


def test_info_loads_neither_libigl_nor_the_solver_nor_the_optional_parts(tmp_path):
    cube = tmp_path / "tet.obj"
    cube.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\n")
    got = _loaded_after(
        f"""
        import contextlib, io
        from igljoin.cli import main
        with contextlib.redirect_stdout(io.StringIO()):
            assert main(["info", {str(cube)!r}]) == 0
        """
    )
    # numpy and scipy.sparse (connected components) are what it needs
    unneeded = {"igl", "scipy.spatial", "numba", "pymeshlab", "polyscope", "PIL", "dask"}
    assert not unneeded & set(got["loaded"]), got


def test_functions_named_like_their_submodule_stay_functions():
    """``igljoin.join``/``clean``/``weld`` are the functions, whichever is imported first."""
    got = _loaded_after(
        """
        import sys
        import igljoin.join, igljoin.clean, igljoin.weld  # the submodules load first here
        from igljoin.join import JoinSolver
        import igljoin
        assert callable(igljoin.join) and igljoin.join.__name__ == "join"
        assert callable(igljoin.clean) and igljoin.clean.__name__ == "clean"
        assert callable(igljoin.weld) and igljoin.weld.__name__ == "weld"
        assert sys.modules["igljoin.join"].JoinSolver is JoinSolver is igljoin.JoinSolver
        """
    )
    assert "numba" in got["loaded"]  # the solver did load here: the probe saw real imports


def test_every_submodule_is_an_attribute_of_the_package():
    """Each ``igljoin/<name>.py`` and sub-package is ``igljoin.<name>`` without an import.

    The three sharing their name with a public function (``join``, ``clean``,
    ``weld``) are that function instead.
    """
    package = Path(igljoin.__file__).parent
    names = {p.stem for p in package.glob("*.py")} | {
        p.parent.name for p in package.glob("*/__init__.py")
    }
    names -= {"__init__"}
    shadowed = {n for n in names if callable(getattr(igljoin, n, None))}
    assert shadowed == {"join", "clean", "weld"}
    got = _loaded_after(
        f"""
        import types, igljoin
        for name in {sorted(names - shadowed)!r}:
            assert isinstance(getattr(igljoin, name), types.ModuleType), name
        """
    )
    assert "numba" in got["loaded"]  # the probe imported the solver's modules for real


def test_every_public_name_resolves():
    names = set(igljoin.__all__)
    assert names <= set(dir(igljoin))
    for name in sorted(names):
        value = getattr(igljoin, name)
        assert getattr(value, "__name__", name).rsplit(".", 1)[-1] == name, name
    assert igljoin.phantoms.__name__ == "igljoin.phantoms"
    try:
        igljoin.no_such_name  # noqa: B018
    except AttributeError as exc:
        assert "no_such_name" in str(exc)
    else:
        raise AssertionError("a missing name did not raise AttributeError")
