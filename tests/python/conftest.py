"""Shared fixtures of the Python module's tests: the module, the CLI next to it, small scenes.

Run from the repository with the build directory on the path:
    PYTHONPATH=build /usr/bin/python3 -m pytest tests/python
PENUMBRA_BINARY overrides the `penumbra` program (default: the one beside the module).
"""
import copy
import json
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
if "PYTHONPATH" not in os.environ:
    sys.path.insert(0, os.path.join(ROOT, "build"))

import penumbra  # noqa: E402

# An analytic sphere and a level-set box over a plane under one light: shadowed, so shadow rays
# are cast, and both kinds of obstacle (their ray offsets differ). Builds in a fraction of a
# second.
SCENE = {
    "camera": {"eye": [0, -6, 3], "look_at": [0, 0, 0.5], "width": 40, "height": 30},
    "lights": [{"name": "key", "type": "rect", "corner": [-1, -1, 4], "edge_u": [0, 2, 0],
                "edge_v": [2, 0, 0], "radiance": [4, 4, 4]}],
    "obstacles": [
        {"name": "ball", "type": "sphere", "center": [-0.3, 0.2, 1.2], "radius": 0.45,
         "analytic": True},
        {"name": "cube", "type": "box", "center": [0.6, -0.4, 0.8], "size": [0.5, 0.5, 0.5]},
    ],
    "receivers": [{"type": "plane", "point": [0, 0, 0], "normal": [0, 0, 1]}],
    "level_set": {"voxel_size": 0.04, "half_width": 3},
}


@pytest.fixture(scope="session")
def cli():
    """The `penumbra` program built with the module."""
    path = os.environ.get("PENUMBRA_BINARY") or os.path.join(
        os.path.dirname(penumbra.__file__), "penumbra")
    if not os.access(path, os.X_OK):
        pytest.fail(f"no penumbra program at {path} (set PENUMBRA_BINARY)")
    return path


@pytest.fixture
def scene_dict():
    return copy.deepcopy(SCENE)


@pytest.fixture(scope="session")
def scene_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("scene") / "scene.json"
    path.write_text(json.dumps(SCENE))
    return str(path)


@pytest.fixture(scope="session")
def scene(scene_file):
    return penumbra.Scene.load(scene_file)


def run_cli(cli, *args, stdin=None, check=True):
    """Runs the program; returns (code, stdout, stderr)."""
    proc = subprocess.run([cli, *map(str, args)], input=stdin, capture_output=True, text=True,
                          timeout=120)
    if check and proc.returncode != 0:
        raise AssertionError(f"penumbra {' '.join(map(str, args))} failed: {proc.stderr}")
    return proc.returncode, proc.stdout, proc.stderr
