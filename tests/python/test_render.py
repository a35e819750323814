"""Scene.render gives the picture and statistics of `penumbra render`."""
import json

import numpy as np
import pytest

import penumbra
from conftest import run_cli


def read_exr(path):
    """Through OpenImageIO's own Python module when installed (independent of the library's
    reader), else through penumbra.read_image."""
    try:
        import OpenImageIO as oiio
    except ImportError:
        return penumbra.read_image(path)
    buf = oiio.ImageBuf(str(path))
    assert buf.spec().format == oiio.FLOAT, "the program writes 32-bit float EXR"
    return np.asarray(buf.get_pixels(oiio.FLOAT), dtype=np.float32)


VOLATILE = {"seconds"}  # wall times


def without_times(stats):
    out = {k: v for k, v in stats.items() if k not in VOLATILE and k != "build"}
    out["build"] = {k: v for k, v in stats["build"].items() if k != "seconds"}
    out["build"]["obstacles"] = [{k: v for k, v in o.items() if k != "seconds"}
                                 for o in stats["build"]["obstacles"]]
    return out


@pytest.mark.parametrize("method,settings,flags", [
    ("aci", {"max_span": 8}, ["--max-span", "8"]),
    ("aci-pixel", {"aci_mode": "arcs"}, ["--aci-mode", "arcs"]),
    ("mc-solid-angle", {"samples": 8, "seed": 11}, ["--samples", "8", "--seed", "11"]),
])
def test_render_equals_the_cli_exr(cli, scene_file, scene, tmp_path, method, settings, flags):
    out, stats_file = tmp_path / "cli.exr", tmp_path / "cli.json"
    run_cli(cli, "render", scene_file, "-o", out, "--stats", stats_file, "--width", 40,
            "--height", 30, "--threads", 2, "--method", method, "-q", *flags)
    image, stats = scene.render(40, 30, method=method, threads=2, **settings)
    assert image.dtype == np.float32 and image.shape == (30, 40, 3)
    expected = read_exr(out)
    assert expected.shape == image.shape
    assert np.array_equal(image, expected)
    assert penumbra.compare(image, str(out))["all"]["max"] == 0.0
    assert without_times(stats) == without_times(json.loads(stats_file.read_text()))
    assert stats["shadow_rays"] > 0 and image.max() > 0.0


def test_threads_are_used(scene):
    # Timing-free: the statistics report the arena's workers; the picture does not depend on
    # them.
    one, s1 = scene.render(24, 18, threads=1)
    two, s2 = scene.render(24, 18, threads=2)
    assert s1["threads"] == 1 and s2["threads"] == 2
    assert np.array_equal(one, two)


def test_size_defaults_to_the_camera(scene):
    image, stats = scene.render()
    assert image.shape == (30, 40, 3)
    assert (stats["width"], stats["height"]) == (40, 30)


def test_image_owns_its_pixels(scene):
    image, _ = scene.render(8, 6)
    copy = image.copy()
    del _
    image[0, 0, 0] = 123.0  # writable, and alive after the call
    assert image.flags.owndata is False and image.base is not None
    assert np.array_equal(image[1:], copy[1:])


def test_read_and_write_image_round_trip(tmp_path):
    img = np.arange(4 * 5 * 3, dtype=np.float32).reshape(4, 5, 3) / 7.0
    penumbra.write_image(tmp_path / "a.exr", img)
    assert np.array_equal(penumbra.read_image(tmp_path / "a.exr"), img)
    grey = img[:, :, 0]
    penumbra.write_image(str(tmp_path / "g.exr"), grey)
    assert penumbra.read_image(tmp_path / "g.exr").shape == (4, 5)


def test_compare_matches_the_cli(cli, tmp_path):
    rng = np.random.default_rng(1)
    a = rng.uniform(0, 1, size=(6, 7, 3)).astype(np.float32)
    b = a + rng.normal(0, 0.01, size=a.shape).astype(np.float32)
    mask = (rng.uniform(size=(6, 7)) > 0.5).astype(np.float32)
    for name, img in (("a", a), ("b", b), ("m", mask)):
        penumbra.write_image(tmp_path / f"{name}.exr", img)
    _, out, _ = run_cli(cli, "compare", tmp_path / "a.exr", tmp_path / "b.exr", "--mask",
                        tmp_path / "m.exr", "--json")
    expected = json.loads(out)
    got = penumbra.compare(a, b, mask=mask)
    for key in ("width", "height", "channels", "units", "all", "masked"):
        assert got[key] == expected[key], key
    assert penumbra.compare(tmp_path / "a.exr", str(tmp_path / "b.exr"))["all"] == expected["all"]


def test_camera_inside_an_obstacle_warns(scene_dict):
    scene_dict["camera"]["eye"] = [-0.3, 0.2, 1.2]  # the ball's centre
    inside = penumbra.Scene.from_dict(scene_dict, file="inside.json")
    with pytest.warns(UserWarning, match=r"inside.json: /camera/eye: inside obstacle 'ball'"):
        inside.render(4, 3)


def test_volumes_render_with_alpha_as_the_cli(cli, tmp_path):
    # A small fog cloud seen by the camera: RGBA, as the CLI's EXR.
    scene = {
        "camera": {"eye": [0, -5, 2.5], "look_at": [0, 0, 0.8], "width": 24, "height": 18},
        "lights": [{"name": "key", "corner": [-1, -1, 4], "edge_u": [0, 2, 0],
                    "edge_v": [2, 0, 0], "radiance": [4, 4, 4]}],
        "obstacles": [{"name": "cloud", "type": "fog", "density": 3, "falloff": 0.2,
                       "shape": {"type": "sphere", "center": [0, 0, 1.4], "radius": 0.5}}],
        "receivers": [{"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1]}],
        "level_set": {"voxel_size": 0.05},
    }
    file = tmp_path / "fog.json"
    file.write_text(json.dumps(scene))
    run_cli(cli, "render", file, "-o", tmp_path / "fog.exr", "--threads", 2, "-q",
            "--volume-cache", 8, "--volume-samples", 16)
    fog = penumbra.Scene.load(file)
    image, _ = fog.render(threads=2, volume_cache=8, volume_samples=16)
    assert image.shape == (18, 24, 4)
    assert np.array_equal(image, read_exr(tmp_path / "fog.exr"))
    assert 0.0 < image[..., 3].max() <= 1.0
    hidden, _ = fog.render(threads=2, hide_volumes=True)
    assert hidden.shape == (18, 24, 3)
    with pytest.raises(TypeError, match="volume_cache only applies to render"):
        fog.probe([[0, 0, 0]], [[0, 0, 1]], volume_cache=4)
