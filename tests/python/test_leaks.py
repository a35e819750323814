"""No memory is kept across calls: 1,000 calls of each kind grow the resident set by little."""
import gc

import numpy as np
import pytest

import penumbra


def rss_bytes():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096


def growth(call, count):
    for _ in range(50):  # warm-up: arenas, thread pools, allocator caches
        call()
    gc.collect()
    before = rss_bytes()
    for _ in range(count):
        call()
    gc.collect()
    return rss_bytes() - before


def test_probe_does_not_leak(scene):
    rng = np.random.default_rng(3)
    points = rng.uniform(-1, 1, size=(64, 3)) * [1, 1, 0]
    normals = np.tile([0.0, 0.0, 1.0], (64, 1))
    # 1,000 calls of 64 points return ~2.5 MB of arrays in all; a leak of the results or of
    # the per-call workers would show several times that.
    assert growth(lambda: scene.probe(points, normals, threads=2), 1000) < 2 * 2**20


def test_errors_do_not_leak(scene):
    def bad():
        with pytest.raises(penumbra.InputError):
            scene.probe([[0, 0, 0]], [[0, 0, 0]])
        with pytest.raises(penumbra.InputError):
            penumbra.Scene.from_dict({"lights": 3})
    assert growth(bad, 1000) < 2 * 2**20


def test_render_and_scenes_do_not_leak(scene_dict):
    scene_dict["obstacles"] = [o for o in scene_dict["obstacles"] if o.get("analytic")]

    def cycle():
        s = penumbra.Scene.from_dict(scene_dict)
        s.render(8, 6, threads=2)
    assert growth(cycle, 1000) < 4 * 2**20
