"""Scene.load and Scene.from_dict read the same model; a scene's properties."""
import json

import numpy as np
import pytest

import penumbra
from conftest import SCENE, run_cli


def test_properties(scene, scene_file):
    assert scene.file == scene_file
    assert scene.lights == ["key"]
    assert scene.obstacles == ["ball", "cube"]
    assert scene.camera["width"] == 40 and scene.camera["look_at"] == (0.0, 0.0, 0.5)
    assert [o["name"] for o in scene.build["obstacles"]] == ["ball", "cube"]
    assert "2 obstacles" in repr(scene)
    no_camera = {k: v for k, v in SCENE.items() if k != "camera"}
    assert penumbra.Scene.from_dict(no_camera).camera is None


def test_from_dict_resolves_paths_like_load(cli, scene_file, tmp_path, monkeypatch):
    # A .vdb obstacle named relative to the scene: from_dict resolves it against the folder of
    # `file` (as load does against the file's), or against base_dir.
    run_cli(cli, "bake", scene_file, "-o", tmp_path / "shapes.vdb")
    d = {"lights": [{"name": "key", "corner": [-1, -1, 4], "edge_u": [0, 2, 0],
                     "edge_v": [2, 0, 0]}],
         "obstacles": [{"type": "vdb", "file": "shapes.vdb"}]}
    file = tmp_path / "vdb.json"
    file.write_text(json.dumps(d))
    points = np.array([[0.5, -0.3, 0.0], [-0.2, 0.1, 0.0], [0.0, 0.0, 0.0]])
    normals = np.tile([0.0, 0.0, 1.0], (3, 1))
    expected = penumbra.Scene.load(file).probe(points, normals)["form_factor"]
    assert expected.min() < expected.max()  # shadowed somewhere
    monkeypatch.chdir(tmp_path.parent)
    got = penumbra.Scene.from_dict(d, file=str(file)).probe(points, normals)["form_factor"]
    assert np.array_equal(got, expected)
    got = penumbra.Scene.from_dict(d, base_dir=tmp_path).probe(points, normals)["form_factor"]
    assert np.array_equal(got, expected)
    with pytest.raises(penumbra.InputError, match="/obstacles/0/file"):
        penumbra.Scene.from_dict(d)


def test_scenes_are_independent(scene_dict):
    # Two scenes from one dict, one changed: each keeps its own light.
    a = penumbra.Scene.from_dict(scene_dict)
    scene_dict["lights"][0]["corner"] = [-1, -1, 6]
    b = penumbra.Scene.from_dict(scene_dict)
    p, n = [[1.5, 1.5, 0.0]], [[0.0, 0.0, 1.0]]
    assert a.probe(p, n)["form_factor"][0] > b.probe(p, n)["form_factor"][0] > 0.0
