"""Benchmark the start-up of the ``igljoin`` command and of ``import igljoin``.

Usage::

    python pipelines/startup_benchmark.py            # 9 runs of each command
    python pipelines/startup_benchmark.py --runs 15

Each command runs as a fresh process with this checkout first on
``PYTHONPATH`` (so the code measured is this checkout's, not an installed
copy):

- ``python -c pass`` — the interpreter alone, the floor under every figure;
- ``python -c "import igljoin"``;
- ``igljoin --version`` (the console script);
- ``igljoin info cube.obj`` on an 8-vertex, 12-face closed cube.

One untimed run of each command warms the file cache and numba's compiled
cache; the script then prints the median, minimum and maximum wall time of
``--runs`` runs. The targets are ``igljoin --version`` <= 0.5 s and ``igljoin
info`` on a small mesh <= 1 s. The machine may be shared: quote medians, and
compare commands within one run.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

#: Target wall times (seconds) of issue 18.
TARGETS = {"igljoin --version": 0.5, "igljoin info cube.obj": 1.0}

_CUBE_OBJ = """\
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 1
v 1 0 1
v 1 1 1
v 0 1 1
f 1 3 2
f 1 4 3
f 5 6 7
f 5 7 8
f 1 2 6
f 1 6 5
f 2 3 7
f 2 7 6
f 3 4 8
f 3 8 7
f 4 1 5
f 4 5 8
"""


def _console_script() -> list[str]:
    """The ``igljoin`` console script beside this interpreter (else ``python -c`` main())."""
    script = Path(sys.executable).with_name("igljoin")
    if script.exists():
        return [str(script)]
    found = shutil.which("igljoin")
    if found:
        return [found]
    return [sys.executable, "-c", "import sys; from igljoin.cli import main; sys.exit(main())"]


def _time_once(cmd: list[str], env: dict[str, str]) -> float:
    start = time.perf_counter()
    done = subprocess.run(cmd, env=env, capture_output=True, text=True)
    elapsed = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} exited {done.returncode}: {done.stderr.strip()}")
    return elapsed


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=9, help="timed runs per command (default 9)")
    args = ap.parse_args(argv)
    if args.runs < 1:
        ap.error("--runs must be >= 1")

    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])
    script = _console_script()
    with tempfile.TemporaryDirectory() as tmp:
        cube = Path(tmp) / "cube.obj"
        cube.write_text(_CUBE_OBJ)
        commands = {
            "python -c pass": [sys.executable, "-c", "pass"],
            "import igljoin": [sys.executable, "-c", "import igljoin"],
            "igljoin --version": [*script, "--version"],
            "igljoin info cube.obj": [*script, "info", str(cube)],
        }
        for cmd in commands.values():  # warm the file cache and numba's cache
            _time_once(cmd, env)
        times: dict[str, list[float]] = {name: [] for name in commands}
        for _ in range(args.runs):  # interleaved, so load drifts hit every command alike
            for name, cmd in commands.items():
                times[name].append(_time_once(cmd, env))

    print(f"start-up, {args.runs} runs each after one warm-up (seconds)")
    print(f"{'command':<24} {'median':>7} {'min':>7} {'max':>7}  target")
    for name, values in times.items():
        target = TARGETS.get(name)
        verdict = ""
        if target is not None:
            verdict = f"<= {target:g}  {'met' if statistics.median(values) <= target else 'MISSED'}"
        print(
            f"{name:<24} {statistics.median(values):7.3f} {min(values):7.3f} "
            f"{max(values):7.3f}  {verdict}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
