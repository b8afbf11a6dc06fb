"""VTU / legacy VTK output, and PLY that meshio reads: round trips through meshio and VTK.

ParaView reads VTU and VTK through VTK's own readers, which the ``vtk``
wheel provides here; its ``vtkPLYReader`` keeps no custom properties, which
is why igljoin writes VTU beside PLY.
"""

from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np
import pytest

import igljoin
from igljoin import phantoms
from igljoin.cli import main
from igljoin.errors import MeshError, MeshReadError, OptionsError
from igljoin.io import output_formats, read_mesh, write_mesh
from igljoin.mesh import Mesh


def _vtk():
    """VTK (the dev extra's ``vtk`` wheel); tests that need it skip without it."""
    return pytest.importorskip("vtk")


def vtk_to_numpy(array):
    return pytest.importorskip("vtk.util.numpy_support").vtk_to_numpy(array)


def _mesh(seed: int = 0) -> Mesh:
    """Two triangles and a separate one, attributes of every dtype igljoin produces."""
    rng = np.random.default_rng(seed)
    V = rng.standard_normal((6, 3))  # full 53-bit mantissas: lossy storage would show
    F = np.array([[0, 1, 2], [0, 2, 3], [3, 4, 5]])
    return Mesh(
        V,
        F,
        {
            "displacement": rng.standard_normal(6),
            "thickness": rng.random(6).astype(np.float32),
            "source_id": np.arange(6, dtype=np.int64) - 2,
            "seam": np.arange(6) % 2 == 0,
            "normal": rng.standard_normal((6, 3)),
        },
        {"area_ratio": rng.random(3), "label": np.array([0, 1, 1], dtype=np.uint16)},
    )


def _expected_dtype(values: np.ndarray) -> np.dtype:
    return np.dtype(np.uint8) if values.dtype == np.bool_ else values.dtype


def _assert_meshio_equal(read: meshio.Mesh, mesh: Mesh, *, exact: bool = True) -> None:
    # ASCII VTU keeps 12 significant digits (meshio writes '%.11e'): relative 1e-11
    close = (
        np.testing.assert_array_equal
        if exact
        else (lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-11, atol=0))
    )
    close(read.points, mesh.V)
    assert [c.type for c in read.cells] == ["triangle"]
    np.testing.assert_array_equal(read.cells[0].data, mesh.F)
    assert set(read.point_data) == set(mesh.vertex_attributes)
    for name, values in mesh.vertex_attributes.items():
        got = read.point_data[name]
        assert got.dtype.newbyteorder("=") == _expected_dtype(values), name
        close(got, values.astype(got.dtype.newbyteorder("=")))
    assert set(read.cell_data) == set(mesh.face_attributes)
    for name, values in mesh.face_attributes.items():
        got = read.cell_data[name][0]
        assert got.dtype.newbyteorder("=") == _expected_dtype(values), name
        close(got, values)


@pytest.mark.parametrize("suffix", [".vtu", ".vtk"])
@pytest.mark.parametrize("binary", [True, False])
def test_vtk_formats_round_trip_through_meshio(tmp_path, suffix, binary):
    mesh = _mesh()
    path = write_mesh(tmp_path / f"m{suffix}", mesh, binary=binary)
    _assert_meshio_equal(meshio.read(path), mesh, exact=binary or suffix == ".vtk")


def _vtk_read(path: Path):
    vtk = _vtk()
    if path.suffix == ".vtu":
        reader = vtk.vtkXMLUnstructuredGridReader()
    else:
        reader = vtk.vtkUnstructuredGridReader()
        reader.ReadAllScalarsOn()
        reader.ReadAllVectorsOn()
        reader.ReadAllFieldsOn()
    reader.SetFileName(str(path))
    reader.Update()
    return reader.GetOutput()


def _vtk_arrays(data) -> dict:
    return {
        data.GetArrayName(i): vtk_to_numpy(data.GetArray(i))
        for i in range(data.GetNumberOfArrays())
    }


def _assert_vtk_equal(grid, mesh: Mesh, extra_point=(), extra_cell=()) -> None:
    np.testing.assert_array_equal(vtk_to_numpy(grid.GetPoints().GetData()), mesh.V)
    assert grid.GetNumberOfCells() == mesh.n_faces
    cells = vtk_to_numpy(grid.GetCells().GetConnectivityArray()).reshape(-1, 3)
    np.testing.assert_array_equal(cells, mesh.F)
    points, faces = _vtk_arrays(grid.GetPointData()), _vtk_arrays(grid.GetCellData())
    assert set(points) == set(mesh.vertex_attributes) | set(extra_point)
    assert set(faces) == set(mesh.face_attributes) | set(extra_cell)
    for name, values in mesh.vertex_attributes.items():
        assert points[name].dtype == _expected_dtype(values), name
        np.testing.assert_array_equal(points[name], values)
    for name, values in mesh.face_attributes.items():
        assert faces[name].dtype == _expected_dtype(values), name
        np.testing.assert_array_equal(faces[name], values)


@pytest.mark.parametrize("suffix", [".vtu", ".vtk"])
def test_vtk_readers_see_every_array(tmp_path, suffix):
    """What ParaView opens: VTK's XML and legacy readers find every array, exactly."""
    mesh = _mesh(1)
    _assert_vtk_equal(_vtk_read(write_mesh(tmp_path / f"m{suffix}", mesh)), mesh)


def test_ply_reads_with_meshio(tmp_path):
    """meshio 5.3.5 misreads per-face properties of binary PLY, so those files are ASCII."""
    mesh = _mesh(2)
    scalars = {k: v for k, v in mesh.vertex_attributes.items() if k != "normal"}
    with_faces = write_mesh(tmp_path / "faces.ply", mesh)
    assert with_faces.read_bytes().startswith(b"ply\nformat ascii 1.0\n")
    got = meshio.read(with_faces)
    np.testing.assert_array_equal(got.points, mesh.V)
    np.testing.assert_array_equal(got.cells[0].data, mesh.F)
    for j in range(3):
        np.testing.assert_array_equal(
            got.point_data[f"normal_{j}"], mesh.vertex_attributes["normal"][:, j]
        )
    for name, values in scalars.items():
        np.testing.assert_array_equal(got.point_data[name], values)
    for name, values in mesh.face_attributes.items():
        np.testing.assert_array_equal(got.cell_data[name][0], values)
    plain = Mesh(mesh.V, mesh.F, scalars)  # no face attributes: binary
    binary = write_mesh(tmp_path / "plain.ply", plain)
    assert binary.read_bytes().startswith(b"ply\nformat binary_little_endian 1.0\n")
    got = meshio.read(binary)
    np.testing.assert_array_equal(got.points, mesh.V)
    np.testing.assert_array_equal(got.cells[0].data, mesh.F)
    for name, values in plain.vertex_attributes.items():
        np.testing.assert_array_equal(got.point_data[name], values)


def test_vtk_attribute_that_cannot_be_stored_writes_nothing(tmp_path):
    mesh = Mesh(_mesh().V, _mesh().F, {"tag": np.array(list("abcdef"))})
    with pytest.raises(MeshError, match="vertex attribute 'tag' has dtype <U1, which VTK cannot"):
        write_mesh(tmp_path / "m.vtu", mesh)
    assert list(tmp_path.iterdir()) == []


def test_vtu_is_written_not_read(tmp_path):
    path = write_mesh(tmp_path / "m.vtu", _mesh())
    with pytest.raises(MeshReadError, match=r"igljoin writes \.vtu/\.vtk but reads only these"):
        read_mesh(path)


# --------------------------------------------------------------------------- saved results


@pytest.fixture(scope="module")
def joined():
    s = phantoms.paper_sample("end_to_end", "equal", resolution=0.5)
    return s, igljoin.JoinSolver(s.host, s.guest, s.host_curve, s.guest_curve).solve()


def test_save_writes_vtu_with_every_result_array(joined, tmp_path):
    _, res = joined
    paths = res.save(tmp_path)
    assert paths["guest_vtu"] == tmp_path / "guest.vtu"
    assert paths["merged_vtu"] == tmp_path / "merged.vtu"
    for key, mesh in (("guest", res.guest), ("merged", res.merged.mesh)):
        assert {"displacement", "strain", "seam"} <= set(mesh.vertex_attributes)
        assert "area_ratio" in mesh.face_attributes
        _assert_meshio_equal(meshio.read(paths[f"{key}_vtu"]), mesh)
        _assert_vtk_equal(_vtk_read(paths[f"{key}_vtu"]), mesh)
        # the PLY file (ASCII: it has face properties) reads with meshio, quality copies added
        ply = meshio.read(paths[key])
        np.testing.assert_array_equal(ply.points, mesh.V)
        np.testing.assert_array_equal(
            ply.point_data["quality"], mesh.vertex_attributes["displacement"]
        )
        np.testing.assert_array_equal(
            ply.cell_data["area_ratio"][0], mesh.face_attributes["area_ratio"]
        )


def test_save_formats_option(joined, tmp_path):
    _, res = joined
    paths = res.save(tmp_path / "a", formats="vtk")
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == [
        "guest.vtk",
        "merged.vtk",
        "report.json",
    ]
    assert set(paths) == {"guest", "merged", "report"}
    paths = res.save(tmp_path / "b", formats=[".PLY"], merged=False)
    assert sorted(p.name for p in (tmp_path / "b").iterdir()) == ["guest.ply", "report.json"]
    with pytest.raises(OptionsError) as info:
        res.save(tmp_path / "c", formats="ply,vtp")
    assert str(info.value) == (
        "unknown output format 'vtp'; choose from obj, off, ply, stl, vtu, vtk (e.g. 'ply,vtu')"
    )
    assert not (tmp_path / "c").exists()
    assert output_formats(" VTU, ply ,vtu") == ("vtu", "ply")
    with pytest.raises(OptionsError, match="no output format given"):
        output_formats([])
    with pytest.raises(OptionsError, match="must be names such as 'ply,vtu', not int"):
        output_formats(3)


def test_cli_formats_flag(tmp_path, capsys):
    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.4)
    host = write_mesh(tmp_path / "host.ply", s.host)
    guest = write_mesh(tmp_path / "guest.obj", s.guest)
    out = tmp_path / "out"
    host_loop = "0"
    code = main(
        [
            "join",
            str(host),
            str(guest),
            "-o",
            str(out),
            "--formats",
            "ply,vtk",
            "--host-loop",
            host_loop,
        ]
    )
    assert code == 0, capsys.readouterr().err
    names = sorted(p.name for p in out.iterdir())
    assert names == [
        ".igljoin-manifest.json",  # the record of what igljoin wrote there
        "guest.ply",
        "guest.vtk",
        "merged.ply",
        "merged.vtk",
        "report.json",
        "timings.json",
    ]
    with pytest.raises(SystemExit) as info:
        main(["join", str(host), str(guest), "-o", str(tmp_path / "x"), "--formats", "gltf"])
    assert info.value.code == 2
    assert "argument --formats: unknown output format 'gltf'" in capsys.readouterr().err


def test_batch_formats_reach_every_case(tmp_path):
    """run_batch(formats=...) (igljoin batch --formats) passes the formats to each case."""
    from igljoin.pipeline import run_batch

    s = phantoms.paper_sample("partial_patch", "equal", resolution=0.4)
    case = tmp_path / "cases" / "one"
    case.mkdir(parents=True)
    write_mesh(case / "host.ply", s.host)
    write_mesh(case / "guest.obj", s.guest)
    (case / "join.toml").write_text("[host_curve]\nloop = 0\n", encoding="utf-8")
    summary = run_batch(
        tmp_path / "cases", tmp_path / "out", workers=0, formats="vtk,ply", progress=False
    )
    assert summary.ok, summary.message()
    names = sorted(p.name for p in (tmp_path / "out" / "one").iterdir())
    assert names == [
        ".igljoin-manifest.json",  # the record of what igljoin wrote there
        "guest.ply",
        "guest.vtk",
        "merged.ply",
        "merged.vtk",
        "report.json",
        "timings.json",
    ]
    merged = meshio.read(tmp_path / "out" / "one" / "merged.vtk")
    assert {"label", "source_face", "area_ratio"} <= set(merged.cell_data)
    with pytest.raises(OptionsError, match="unknown output format 'png'"):
        run_batch(tmp_path / "cases", tmp_path / "out2", workers=0, formats="png")
