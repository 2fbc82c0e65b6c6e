"""Mesh and task files, and the `maptidal` command line."""

import json
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from maptidal.cli import main
from maptidal.discovery import DiscoveryInputError, discover
from maptidal.files import load_keypoints, load_mesh, load_tasks, save_tasks
from maptidal.synthetic import wall_keyframe_mesh


@pytest.fixture
def keyframe():
    return wall_keyframe_mesh(0.0, width=1.7, height=1.3, seed=5)


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".stl"])
def test_meshes_load_in_file_order(tmp_path, keyframe, suffix):
    vertices, faces = keyframe
    path = tmp_path / f"frame{suffix}"
    trimesh.Trimesh(vertices, faces, process=False).export(path)
    loaded_vertices, loaded_faces = load_mesh(path)
    # STL stores each triangle's corners, so compare the triangles themselves.
    np.testing.assert_allclose(loaded_vertices[loaded_faces], vertices[faces], atol=1e-6)
    if suffix != ".stl":  # STL repeats vertices, which changes the keypoint count
        assert discover(loaded_vertices, loaded_faces).counts == discover(vertices, faces).counts


def test_keypoints_from_npy_and_ply(tmp_path):
    points = np.random.default_rng(0).uniform(size=(50, 3))
    np.save(tmp_path / "k.npy", points)
    trimesh.PointCloud(points).export(tmp_path / "k.ply")
    np.testing.assert_array_equal(load_keypoints(tmp_path / "k.npy"), points)
    np.testing.assert_allclose(load_keypoints(tmp_path / "k.ply"), points, atol=1e-6)


def test_tasks_round_trip_and_validation(tmp_path):
    rows = np.array([[0, 1, 2, 0, 0, -1.0], [3, 4, 5, 1, 0, 0]])
    path = save_tasks(tmp_path / "t.json", rows, counts={"final": 2})
    np.testing.assert_array_equal(load_tasks(path), rows)
    bad = tmp_path / "bad.json"
    for document, message in [
        ({"tasks": [{"position": [0, 0, 0], "direction": [0, 0, 2]}]}, "unit"),
        ({"tasks": [{"position": [0, 0], "direction": [0, 0, 1]}]}, "position"),
        ({"tasks": [{"position": [0, 0, "a"], "direction": [0, 0, 1]}]}, "non-numeric"),
        ({"no": "tasks"}, "tasks"),
    ]:
        bad.write_text(json.dumps(document))
        with pytest.raises(DiscoveryInputError, match=message):
            load_tasks(bad)
    bad.write_text("{not json")
    with pytest.raises(DiscoveryInputError, match="JSON"):
        load_tasks(bad)


def test_missing_and_malformed_files_get_clear_errors(tmp_path):
    with pytest.raises(DiscoveryInputError, match="not found"):
        load_mesh(tmp_path / "missing.ply")
    (tmp_path / "mesh.xyz").write_text("1 2 3\n")
    with pytest.raises(DiscoveryInputError, match="unsupported"):
        load_mesh(tmp_path / "mesh.xyz")
    (tmp_path / "broken.ply").write_bytes(b"ply\nformat garbage\n")
    with pytest.raises(DiscoveryInputError):
        load_mesh(tmp_path / "broken.ply")
    with pytest.raises(DiscoveryInputError, match="not found"):
        load_tasks(tmp_path / "missing.json")


def test_cli_discover_json_shape_and_chaining(tmp_path, keyframe, capsys):
    vertices, faces = keyframe
    mesh1 = tmp_path / "frame1.ply"
    trimesh.Trimesh(vertices, faces, process=False).export(mesh1)
    out1 = tmp_path / "tasks1.json"
    assert (
        main(
            [
                "discover",
                str(mesh1),
                "--json",
                "--out",
                str(out1),
                "--plot",
                str(tmp_path / "f1.png"),
            ]
        )
        == 0
    )
    document = json.loads(capsys.readouterr().out)
    assert set(document) == {"counts", "tasks", "params"}
    assert set(document["counts"]) == {"cips", "after_prune", "confirmed", "final"}
    assert document["counts"]["final"] == len(document["tasks"]) > 0
    assert all(set(t) == {"position", "direction"} for t in document["tasks"])
    assert document["params"]["range_m"] == 2.0
    assert json.loads(out1.read_text())["tasks"] == document["tasks"]
    assert (tmp_path / "f1.png").stat().st_size > 10_000

    v2, f2 = wall_keyframe_mesh(0.6, width=1.7, height=1.3, seed=6)
    mesh2 = tmp_path / "frame2.obj"
    trimesh.Trimesh(v2, f2, process=False).export(mesh2)
    assert main(["discover", str(mesh2), "--existing", str(out1), "--json"]) == 0
    second = json.loads(capsys.readouterr().out)
    expected = discover(*load_mesh(mesh2), existing=load_tasks(out1))
    assert second["counts"] == expected.counts


def test_cli_parameters_reach_discovery(tmp_path, keyframe, capsys):
    mesh = tmp_path / "f.ply"
    trimesh.Trimesh(*keyframe, process=False).export(mesh)
    main(
        [
            "discover",
            str(mesh),
            "--json",
            "--r-ex",
            "0.5",
            "--theta-ex",
            "0.1",
            "--threshold",
            "0.9",
        ]
    )
    loose = json.loads(capsys.readouterr().out)
    main(["discover", str(mesh), "--json"])
    default = json.loads(capsys.readouterr().out)
    assert loose["params"]["r_ex_m"] == 0.5
    assert loose["counts"]["final"] > default["counts"]["final"]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["discover", "missing.ply"], "not found"),
        (["discover", "MESH", "--existing", "missing.json"], "not found"),
        (["discover", "MESH", "--r-ex", "-1"], "r_ex"),
        (["discover", "NANMESH"], "NaN"),
    ],
)
def test_cli_bad_input_exits_2_with_one_line(tmp_path, keyframe, capsys, args, message):
    mesh = tmp_path / "f.ply"
    trimesh.Trimesh(*keyframe, process=False).export(mesh)
    nan_mesh = tmp_path / "nan.obj"
    nan_mesh.write_text("v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n")
    args = [str(mesh) if a == "MESH" else str(nan_mesh) if a == "NANMESH" else a for a in args]
    out = tmp_path / "never.json"
    assert main([*args, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not out.exists()


def test_console_script_help():
    for command in ([], ["discover"], ["demo"]):
        completed = subprocess.run(
            [sys.executable, "-m", "maptidal.cli", *command, "--help"],
            capture_output=True,
            text=True,
            check=True,
        )
        assert "usage: maptidal" in completed.stdout


def test_demo_writes_report_tasks_and_plots(tmp_path):
    assert main(["demo", "--out", str(tmp_path)]) == 0
    report = (tmp_path / "report.md").read_text()
    summary = json.loads((tmp_path / "summary.json").read_text())
    tasks = load_tasks(tmp_path / "tasks.json")
    assert len(tasks) == summary["total_tasks"] == sum(f["final"] for f in summary["frames"])
    assert report.count("\n| ") == len(summary["frames"]) + 1
    assert all((tmp_path / f"frame{i:02d}.png").exists() for i in range(len(summary["frames"])))
    assert not list(tmp_path.glob(".*tmp*"))
