"""penumbra.pyi describes the module: the same names, the same arguments."""
import ast
import inspect
import os

import penumbra


def stub_tree():
    path = os.path.join(os.path.dirname(penumbra.__file__), "penumbra.pyi")
    assert os.path.exists(path), "the build copies penumbra.pyi next to the module"
    with open(path) as f:
        return ast.parse(f.read())


def public(names):
    return {n for n in names if not n.startswith("_")}


def stub_names(body):
    names = set()
    for node in body:
        if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.AnnAssign):
            names.add(node.target.id)
        elif isinstance(node, ast.Assign):
            names.update(t.id for t in node.targets)
    return public(names)


def test_module_names_are_in_the_stub():
    tree = stub_tree()
    module = public(n for n in dir(penumbra) if not inspect.ismodule(getattr(penumbra, n)))
    assert stub_names(tree.body) == module


def test_scene_members_are_in_the_stub():
    tree = stub_tree()
    scene = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "Scene")
    assert stub_names(scene.body) == public(dir(penumbra.Scene))


def test_function_arguments_match_the_docstrings():
    # pybind11 writes each signature at the head of its docstring.
    tree = stub_tree()
    defs = {n.name: n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)}
    for name, obj in [("probe", penumbra.Scene.probe), ("render", penumbra.Scene.render),
                      ("compare", penumbra.compare), ("load", penumbra.Scene.load),
                      ("from_dict", penumbra.Scene.from_dict)]:
        doc_sig = obj.__doc__.split("\n")[0]
        args = [a.arg for a in defs[name].args.args if a.arg != "self"]
        for arg in args:
            assert f"{arg}:" in doc_sig, (name, arg, doc_sig)
    assert penumbra.Scene.probe.__doc__ and penumbra.compare.__doc__
