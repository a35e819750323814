"""Scene.probe gives the numbers of `penumbra probe`, whatever the thread count."""
import numpy as np
import pytest

import penumbra
from conftest import run_cli


def sensor_points():
    """Points on the floor across both shadows, on the obstacles' surfaces (rays start off a
    level set's surface there) and with tilted, unnormalized normals (the light partly below
    the horizon)."""
    rng = np.random.default_rng(7)
    xs = np.linspace(-1.6, 1.6, 41)
    floor = np.stack([xs, 0.25 * xs, np.zeros_like(xs)], axis=1)
    floor_n = np.tile([0.0, 0.0, 1.0], (len(xs), 1))
    d = rng.normal(size=(24, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ball = np.array([-0.3, 0.2, 1.2]) + 0.45 * d
    cube = np.array([0.6, -0.4, 0.8]) + np.array([0.0, 0.0, 0.25]) + 0.2 * rng.uniform(
        -1, 1, size=(12, 3)) * [1, 1, 0]
    cube_n = np.tile([0.0, 0.0, 1.0], (12, 1))
    tilted = rng.uniform(-1.5, 1.5, size=(16, 3)) * [1, 1, 0]
    tilted_n = rng.normal(size=(16, 3)) * 3.0 + [0, 0, 2.0]
    points = np.concatenate([floor, ball, cube, tilted])
    normals = np.concatenate([floor_n, 2.5 * d, cube_n, tilted_n])
    return points, normals


def csv_of(points, normals):
    # repr() round-trips: the program parses the same doubles.
    rows = ["x,y,z,nx,ny,nz"]
    rows += [",".join(repr(float(v)) for v in (*p, *n)) for p, n in zip(points, normals)]
    return "\n".join(rows) + "\n"


def cli_probe(cli, scene_file, points, normals, *flags):
    _, out, _ = run_cli(cli, "probe", scene_file, *flags, stdin=csv_of(points, normals))
    lines = out.strip().split("\n")
    header = lines[0].split(",")
    return header, [line.split(",") for line in lines[1:]]


def g12(v):
    """A double as the program writes it (ostream, precision 12: printf's %.12g)."""
    return "%.12g" % v


def assert_same_as_cli(result, points, header, rows):
    assert len(rows) == len(points)
    col = {name: i for i, name in enumerate(header)}
    for i, row in enumerate(rows):
        expected = {
            "x": g12(points[i, 0]), "y": g12(points[i, 1]), "z": g12(points[i, 2]),
            "form_factor": g12(result["form_factor"][i]),
            "dF_dx": g12(result["gradient"][i, 0]),
            "dF_dy": g12(result["gradient"][i, 1]),
            "dF_dz": g12(result["gradient"][i, 2]),
            "shadow_rays": str(int(result["shadow_rays"][i])),
        }
        if "error_bound" in col:
            expected["error_bound"] = g12(result["error_bound"][i])
        got = {name: row[col[name]] for name in expected}
        assert got == expected, f"point {i}"


@pytest.mark.parametrize("mode", ["tangent", "arcs", "paper"])
def test_aci_equals_the_cli_csv(cli, scene_file, scene, mode):
    points, normals = sensor_points()
    result = scene.probe(points, normals, aci_mode=mode, aci_grid=3, aci_steps=4, threads=2)
    flags = ["--aci-mode", mode, "--aci-grid", "3", "--aci-steps", "4"]
    if mode == "tangent":
        flags.append("--error-bound")
    header, rows = cli_probe(cli, scene_file, points, normals, *flags)
    assert ("error_bound" in result) == (mode == "tangent")
    assert_same_as_cli(result, points, header, rows)
    # Not all trivially lit or dark: the points cross penumbrae.
    ff = result["form_factor"]
    assert np.count_nonzero((ff > 0.0) & (ff < ff.max())) > 20
    assert result["shadow_rays"].sum() > 0


@pytest.mark.parametrize("method,flags", [
    ("mc-solid-angle", {"samples": 64, "seed": 5}),
    ("mc-adaptive", {"mc_threshold": 0.02, "mc_max_depth": 6, "mc_initial_depth": 1}),
    ("reference", {}),
    ("mc-ratio", {"seed": 2**64 - 1}),
])
def test_monte_carlo_equals_the_cli_csv(cli, scene_file, scene, method, flags):
    points, normals = sensor_points()
    result = scene.probe(points, normals, method=method, threads=2, **flags)
    cli_flags = ["--method", method]
    for key, value in flags.items():
        cli_flags += ["--" + key.replace("_", "-"), str(value)]
    header, rows = cli_probe(cli, scene_file, points, normals, *cli_flags)
    assert "error_bound" not in result
    assert_same_as_cli(result, points, header, rows)
    assert not result["gradient"].any()  # Monte Carlo methods give no gradient


def test_results_do_not_depend_on_the_thread_count(scene):
    points, normals = sensor_points()
    points = np.tile(points, (8, 1))  # several chunks' worth of tasks
    normals = np.tile(normals, (8, 1))
    one = scene.probe(points, normals, threads=1)
    two = scene.probe(points, normals, threads=2)
    assert one["threads"] == 1 and two["threads"] == 2
    for key in ("form_factor", "gradient", "shadow_rays", "error_bound"):
        assert np.array_equal(one[key], two[key], equal_nan=True), key
    mc1 = scene.probe(points, normals, method="mc-ratio", seed=3, threads=1)
    mc2 = scene.probe(points, normals, method="mc-ratio", seed=3, threads=2)
    assert np.array_equal(mc1["form_factor"], mc2["form_factor"])


def test_threads_default_to_every_hardware_thread(scene):
    import os
    points, normals = sensor_points()
    assert scene.probe(points, normals)["threads"] == len(os.sched_getaffinity(0))


def test_arrays_shapes_and_types(scene):
    points, normals = sensor_points()
    r = scene.probe(points.tolist(), normals.astype(np.float32), light="key")
    n = len(points)
    assert r["form_factor"].shape == (n,) and r["form_factor"].dtype == np.float64
    assert r["gradient"].shape == (n, 3) and r["gradient"].dtype == np.float64
    assert r["shadow_rays"].shape == (n,) and r["shadow_rays"].dtype == np.int64
    assert r["error_bound"].shape == (n,)
    # Lists and float32 normals give what float64 arrays give (the normals are normalized).
    ref = scene.probe(points, normals.astype(np.float32).astype(np.float64))
    assert np.array_equal(r["form_factor"], ref["form_factor"])
    empty = scene.probe(np.zeros((0, 3)), np.zeros((0, 3)))
    assert empty["form_factor"].shape == (0,) and empty["gradient"].shape == (0, 3)


def test_non_contiguous_input_is_read_correctly(scene):
    points, normals = sensor_points()
    wide = np.zeros((len(points), 6))
    wide[:, 0:3] = points
    wide[:, 3:6] = normals
    a = scene.probe(wide[:, 0:3], wide[:, 3:6])
    b = scene.probe(points, normals)
    assert np.array_equal(a["form_factor"], b["form_factor"])


def lambert(point, normal, polygon):
    """Lambert's polygon formula: F = 1/(2 pi) sum_i angle_i (unit(R_i x R_i+1) . n)."""
    r = np.asarray(polygon, float) - point
    total = 0.0
    for i in range(len(r)):
        a, b = r[i], r[(i + 1) % len(r)]
        c = np.cross(a, b)
        angle = np.arctan2(np.linalg.norm(c), np.dot(a, b))
        total += angle * np.dot(c / np.linalg.norm(c), normal)
    return abs(total) / (2 * np.pi)


def test_unoccluded_points_match_lamberts_formula(scene_dict):
    scene_dict["obstacles"] = []
    open_scene = penumbra.Scene.from_dict(scene_dict)
    points = np.array([[0.0, 0.0, 0.0], [0.7, -0.3, 0.5], [2.0, 1.0, 0.0]])
    normals = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [-0.3, 0.1, 1.0]])
    r = open_scene.probe(points, normals)
    corner = np.array([-1.0, -1.0, 4.0])
    eu, ev = np.array([0.0, 2.0, 0.0]), np.array([2.0, 0.0, 0.0])
    light = [corner, corner + eu, corner + eu + ev, corner + ev]
    for i in range(len(points)):
        n = normals[i] / np.linalg.norm(normals[i])
        assert r["form_factor"][i] == pytest.approx(lambert(points[i], n, light), rel=1e-12)
        assert r["shadow_rays"][i] <= 1  # one ray, whose certificate covers the light


def test_all_lights_equal_the_cli(cli, tmp_path):
    """light='all' adds the lights (a rectangle, a polygon, a disc) as `probe --light all`
    does, and per_light holds each one's form factor as `--columns per-light`."""
    scene_file = tmp_path / "lights.json"
    scene_file.write_text("""{
      "lights": [{"name": "key", "corner": [-1,-1,4], "edge_u": [0,2,0], "edge_v": [2,0,0]},
                 {"name": "hex", "type": "polygon",
                  "vertices": [[2,0,3],[1,-0.8,3],[0,0,3],[0.5,0.9,3],[1.5,0.9,3]]},
                 {"name": "round", "type": "disc", "center": [-1.5,0.5,3],
                  "normal": [0,0,-1], "radius": 0.5}],
      "obstacles": [{"type": "sphere", "center": [0.3,0.2,2.0], "radius": 0.7,
                     "analytic": true}]
    }""")
    scene = penumbra.Scene.load(str(scene_file))
    points = np.array([[-2.0, 0.3, 0.0], [1.2, 0.43, 0.0], [0.6, 0.4, 0.0]])
    normals = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0], [0.3, 0.0, 1.0]])
    result = scene.probe(points, normals, light="all")
    header, rows = cli_probe(cli, str(scene_file), points, normals, "--light", "all",
                             "--columns", "per-light", "--error-bound")
    assert_same_as_cli(result, points, header, rows)
    assert result["per_light"].shape == (3, 3)
    for k, name in enumerate(["key", "hex", "round"]):
        column = header.index("form_factor:" + name)
        assert [row[column] for row in rows] == [g12(v) for v in result["per_light"][:, k]]
        one = scene.probe(points, normals, light=name)
        assert np.array_equal(one["form_factor"], result["per_light"][:, k])
