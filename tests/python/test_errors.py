"""Bad input raises penumbra.InputError (a ValueError) with the CLI's message."""
import json
import os

import numpy as np
import pytest

import penumbra
from conftest import run_cli

PREFIX = "penumbra: error: "


def cli_error(cli, *args, stdin=None):
    code, _, err = run_cli(cli, *args, stdin=stdin, check=False)
    assert code == 2, err
    line = err.strip()
    assert line.startswith(PREFIX)
    return line[len(PREFIX):]


@pytest.mark.parametrize("path,value", [
    (("obstacles", 0, "radius"), -1),
    (("lights", 0, "edge_u"), [0, 0]),
    (("camera", "fov_deg"), "wide"),
    (("receivers", 0, "colour"), [1, 1, 1]),
])
def test_scene_errors_are_the_clis(cli, scene_dict, tmp_path, path, value):
    node = scene_dict
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    file = tmp_path / "bad.json"
    file.write_text(json.dumps(scene_dict))
    expected = cli_error(cli, "probe", file, stdin="x,y,z,nx,ny,nz\n")
    with pytest.raises(penumbra.InputError) as loaded:
        penumbra.Scene.load(file)
    assert str(loaded.value) == expected
    with pytest.raises(penumbra.InputError) as parsed:
        penumbra.Scene.from_dict(scene_dict, file=str(file))
    assert str(parsed.value) == expected
    assert isinstance(parsed.value, ValueError)
    assert parsed.value.file == str(file)
    assert expected == f"{file}: {parsed.value.where}: {parsed.value.message}"


def test_missing_scene_file(cli, tmp_path):
    missing = tmp_path / "nope.json"
    expected = cli_error(cli, "probe", missing, stdin="")
    with pytest.raises(penumbra.InputError, match="no such file") as e:
        penumbra.Scene.load(str(missing))
    assert str(e.value) == expected


def test_not_json(scene_dict):
    scene_dict["background"] = [float("nan"), 0, 0]
    with pytest.raises(penumbra.InputError, match="not a JSON document"):
        penumbra.Scene.from_dict(scene_dict)
    with pytest.raises(TypeError):
        penumbra.Scene.from_dict([1, 2])


@pytest.mark.parametrize("kw,flag", [
    ({"aci_grid": 40}, "--aci-grid"),
    ({"aci_steps": 0}, None),
    ({"aci_mode": "fast"}, "--aci-mode"),
    ({"samples": 0}, None),
    ({"mc_max_depth": 25}, None),
    ({"mc_threshold": -1.0}, "--mc-threshold"),
])
def test_settings_out_of_range(cli, scene_file, scene, kw, flag):
    (key, value), = kw.items()
    pts = np.zeros((1, 3))
    nrm = np.array([[0.0, 0.0, 1.0]])
    method = "mc-adaptive" if key in ("samples", "mc_max_depth", "mc_threshold") else "aci"
    with pytest.raises(penumbra.InputError) as e:
        scene.probe(pts, nrm, method=method, **kw)
    assert e.value.where == key
    assert str(e.value).startswith(key + ": ")
    if flag:  # ranges CLI11 does not check first: the same message after the flag
        expected = cli_error(cli, "probe", scene_file, "--method", method, flag, str(value),
                             stdin="x,y,z,nx,ny,nz\n")
        assert expected == f"{flag}: {e.value.message}"
    lo_hi = penumbra.SETTING_RANGES.get(key)
    if lo_hi:
        assert f"must be in [{lo_hi[0]}, {lo_hi[1]}]" in str(e.value)


def test_unknown_and_misplaced_settings(scene):
    pts, nrm = np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]])
    with pytest.raises(TypeError, match="unknown setting 'grid'.*aci_grid"):
        scene.probe(pts, nrm, grid=4)
    with pytest.raises(TypeError, match="max_span only applies to render"):
        scene.probe(pts, nrm, max_span=4)
    with pytest.raises(TypeError, match="unknown setting 'colour'"):
        scene.render(8, 8, colour=1)
    with pytest.raises(TypeError, match="aci_grid: must be an integer, got float"):
        scene.probe(pts, nrm, aci_grid=2.0)
    with pytest.raises(TypeError, match="must be an integer, got bool"):
        scene.render(8, 8, threads=True)
    with pytest.raises(penumbra.InputError, match="^samples: only applies to the Monte Carlo"):
        scene.probe(pts, nrm, samples=16)
    with pytest.raises(penumbra.InputError, match="^aci_steps: aci_grid x 2"):
        scene.probe(pts, nrm, aci_grid=32, aci_steps=12)
    with pytest.raises(penumbra.InputError, match="^method: probe supports aci"):
        scene.probe(pts, nrm, method="aci-pixel")
    with pytest.raises(penumbra.InputError, match="^method: "):
        scene.render(8, 8, method="magic")
    with pytest.raises(penumbra.InputError, match=r"^threads: must be in \[1, 1024\], got 0"):
        scene.render(8, 8, threads=0)
    with pytest.raises(penumbra.InputError, match=r"^width: must be in \[1, 65536\], got 0"):
        scene.render(0, 8)
    with pytest.raises(penumbra.InputError, match=r"^seed: must be an integer in \[0, 2\^64 - 1\]"):
        scene.probe(pts, nrm, seed=-1)


def test_bad_points(scene):
    nrm = np.array([[0.0, 0.0, 1.0]])
    with pytest.raises(penumbra.InputError, match=r"^points: must have shape \(N, 3\), got \(3,\)"):
        scene.probe(np.zeros(3), nrm)
    with pytest.raises(penumbra.InputError, match=r"^normals: must have as many rows"):
        scene.probe(np.zeros((2, 3)), nrm)
    with pytest.raises(penumbra.InputError,
                       match=r"^points\[0, 1\]: expected a finite number, got nan"):
        scene.probe([[0.0, float("nan"), 0.0]], nrm)
    with pytest.raises(penumbra.InputError, match=r"^points\[0, 2\]: .*at most 1e12"):
        scene.probe([[0.0, 0.0, 2e12]], nrm)
    with pytest.raises(penumbra.InputError, match=r"^normals\[1\]: the normal is zero"):
        scene.probe(np.zeros((2, 3)), [[0, 0, 1], [0, 0, 0]])
    with pytest.raises(TypeError, match="points: expected an array"):
        scene.probe("here", nrm)


def test_light_errors_are_the_clis(cli, scene_file, scene):
    expected = cli_error(cli, "probe", scene_file, "--light", "fill", stdin="x,y,z,nx,ny,nz\n")
    with pytest.raises(penumbra.InputError) as e:
        scene.probe([[0, 0, 0]], [[0, 0, 1]], light="fill")
    assert str(e.value) == expected


def test_render_without_camera(cli, scene_dict, tmp_path):
    del scene_dict["camera"]
    file = tmp_path / "nocam.json"
    file.write_text(json.dumps(scene_dict))
    expected = cli_error(cli, "render", file, "-o", tmp_path / "x.exr", "-q")
    with pytest.raises(penumbra.InputError) as e:
        penumbra.Scene.load(file).render()
    assert str(e.value) == expected


def test_compare_errors(cli, tmp_path):
    a = np.zeros((4, 4, 3), np.float32)
    with pytest.raises(penumbra.InputError, match="^b: "):
        penumbra.compare(a, np.zeros((4, 5, 3), np.float32))
    bad = a.copy()
    bad[1, 2, 0] = np.inf
    with pytest.raises(penumbra.InputError, match="non-finite value .* at pixel 2, 1"):
        penumbra.compare(bad, a)
    missing = str(tmp_path / "missing.exr")
    penumbra.write_image(tmp_path / "a.exr", a)
    expected = cli_error(cli, "compare", missing, tmp_path / "a.exr")
    with pytest.raises(penumbra.InputError) as e:
        penumbra.compare(missing, tmp_path / "a.exr")
    assert str(e.value) == expected.replace("TEST", "a")
    with pytest.raises(penumbra.InputError, match="^path: "):
        penumbra.write_image(tmp_path / "a.tiff", a)
