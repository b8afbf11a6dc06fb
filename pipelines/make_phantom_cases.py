"""Write a folder of case folders built from igljoin's phantoms.

Usage::

    python pipelines/make_phantom_cases.py OUT [--resolution 1.0] [--include-bad]

Writes one case folder per join (``host.*``, ``guest.*``, ``join.toml``):

* the paper's six samples (``end_to_end-*``, ``partial_patch-*``: shorter,
  equal and longer guest seams), with the curves given in the three ways a
  spec allows — vertex indices (end-to-end host), a loop index (end-to-end
  guest), a point that snaps (patch host) and nothing at all (patch guest:
  its only boundary loop);
* ``open_strip-equal``: an open seam, host by indices, guest by start/end points;
* ``partial_patch-coarse``: a guest 5x coarser than the host along the seam,
  resampled to the host seam's edge length before joining (``resample = true``);
* ``partial_patch-stiff``: a per-vertex stiffness read from ``stiffness.npy``.

With ``--include-bad`` two cases that must fail are added: ``bad-mesh`` (its
guest file is not a mesh) and ``bad-outside`` (its spec names a file outside
its folder). Hosts are written as PLY, guests alternately as OBJ and OFF.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import igljoin
from igljoin import phantoms


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    return "[" + ", ".join(_toml_value(v) for v in np.asarray(value).tolist()) + "]"


def _table(name: str, values: dict) -> str:
    lines = [f"[{name}]"] + [f"{k} = {_toml_value(v)}" for k, v in values.items()]
    return "\n".join(lines) + "\n"


def write_case(
    root: Path,
    name: str,
    host: igljoin.Mesh,
    guest: igljoin.Mesh,
    *,
    host_curve: dict | None = None,
    guest_curve: dict | None = None,
    options: dict | None = None,
    description: str = "",
    guest_suffix: str = ".obj",
) -> Path:
    """Write one case folder and return it."""
    folder = root / name
    folder.mkdir(parents=True, exist_ok=True)
    igljoin.write_mesh(folder / "host.ply", host)
    igljoin.write_mesh(folder / f"guest{guest_suffix}", guest)
    parts = [f"# {name}: written by pipelines/make_phantom_cases.py\n"]
    if description:
        parts.append(f"description = {_toml_value(description)}\n")
    for table, values in (
        ("host_curve", host_curve),
        ("guest_curve", guest_curve),
        ("options", options),
    ):
        if values:
            parts.append("\n" + _table(table, values))
    (folder / "join.toml").write_text("".join(parts), encoding="utf-8")
    return folder


def make_cases(root: str | Path, *, resolution: float = 1.0, include_bad: bool = False) -> list:
    """Write the phantom cases into ``root``; return the case folders."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    folders = []
    suffixes = [".obj", ".off"]
    for i, s in enumerate(phantoms.paper_samples(resolution=resolution)):
        name = s.name.replace("/", "-")
        if s.scenario == "end_to_end":
            host_curve = {"indices": s.host_curve}
            guest_curve = {"loop": int(s.guest_curve.loop)}
        else:
            host_curve = {"start": s.host.V[s.host_curve[0]]}
            guest_curve = None
        folders.append(
            write_case(
                root,
                name,
                s.host,
                s.guest,
                host_curve=host_curve,
                guest_curve=guest_curve,
                description=s.description,
                guest_suffix=suffixes[i % 2],
            )
        )
    s = phantoms.paper_sample("open_strip", "equal", resolution=resolution)
    folders.append(
        write_case(
            root,
            "open_strip-equal",
            s.host,
            s.guest,
            host_curve={"indices": s.host_curve},
            guest_curve={
                "start": s.guest.V[s.guest_curve[0]],
                "end": s.guest.V[s.guest_curve[-1]],
                "via": s.guest.V[s.guest_curve[len(s.guest_curve) // 2]],
            },
            description=s.description,
        )
    )
    s = phantoms.paper_sample("partial_patch", "equal", resolution=resolution, guest_resolution=0.2)
    folders.append(
        write_case(
            root,
            "partial_patch-coarse",
            s.host,
            s.guest,
            host_curve={"indices": s.host_curve},
            options={"resample": True},
            description="partial patch whose guest is 5x coarser than the host along the seam, "
            "resampled to the host seam's mean edge before joining",
            guest_suffix=".off",
        )
    )
    s = phantoms.paper_sample("partial_patch", "equal", resolution=resolution)
    folder = write_case(
        root,
        "partial_patch-stiff",
        s.host,
        s.guest,
        host_curve={"loop": 0},
        options={"stiffness": "stiffness.npy", "smooth_weight": 5.0},
        description="partial patch with a stiffer centre (per-vertex stiffness file)",
    )
    centre = s.guest.V.mean(axis=0)
    r = np.linalg.norm(s.guest.V - centre, axis=1)
    np.save(folder / "stiffness.npy", 1.0 + 4.0 * (r < 0.5 * r.max()))
    folders.append(folder)
    if include_bad:
        s = phantoms.paper_sample("partial_patch", "equal", resolution=resolution)
        bad = write_case(root, "bad-mesh", s.host, s.guest, description="guest is not a mesh")
        (bad / "guest.obj").write_text("this is not an OBJ file\nf 1 2 x\n", encoding="utf-8")
        folders.append(bad)
        out = root / "bad-outside"
        out.mkdir(parents=True, exist_ok=True)
        igljoin.write_mesh(out / "guest.obj", s.guest)
        (out / "join.toml").write_text(
            '# the host lives in another case folder: refused\nhost = "../bad-mesh/host.ply"\n',
            encoding="utf-8",
        )
        folders.append(out)
    return folders


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path, help="folder to write the case folders into")
    parser.add_argument(
        "--resolution",
        type=float,
        default=1.0,
        help="phantom resolution (1 = the paper's sizes; 0.4 is fast)",
    )
    parser.add_argument(
        "--include-bad",
        action="store_true",
        help="also write two cases that must fail (bad mesh, path outside the folder)",
    )
    args = parser.parse_args(argv)
    folders = make_cases(args.out, resolution=args.resolution, include_bad=args.include_bad)
    print(f"wrote {len(folders)} cases to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
