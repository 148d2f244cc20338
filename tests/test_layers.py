"""The package's layers (docs/architecture.md): a module imports only from its own layer or
the layers below it, never from above, including imports inside functions."""

import ast
from pathlib import Path

import volmc

#: Lowest first. A module belongs to the layer of its longest matching prefix.
LAYERS = [
    ("volmc.constants", "volmc.params", "volmc.resources", "volmc.scene.errors",
     "volmc.emission", "volmc.outputs"),
    ("volmc.reference",),
    ("volmc.techniques",),
    ("volmc.scene",),
    ("volmc.pack", "volmc.emitters", "volmc.film", "volmc.denoise", "volmc.checkpoint"),
    ("volmc.cl", "volmc.memory"),
    ("volmc.backends",),
    ("volmc.render", "volmc.check", "volmc.distributed"),
    ("volmc.bench", "volmc.peers", "volmc.cli", "volmc"),
]
ROOT = Path(volmc.__file__).parent


def layer_of(module):
    best, layer = -1, None
    for k, prefixes in enumerate(LAYERS):
        for p in prefixes:
            if (module == p or module.startswith(p + ".")) and len(p) > best:
                best, layer = len(p), k
    return layer


def _module_name(path):
    parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _imports(path):
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            yield target
            for a in node.names:   # "from . import x" imports the submodule x
                yield f"{target}.{a.name}"


def test_every_module_has_a_layer():
    for path in ROOT.rglob("*.py"):
        assert layer_of(_module_name(path)) is not None, path


def test_no_module_imports_from_a_higher_layer():
    bad = []
    for path in sorted(ROOT.rglob("*.py")):
        name = _module_name(path)
        own = layer_of(name)
        for target in _imports(path):
            if not target.startswith("volmc.") or target == name:
                continue   # "from .. import params" names the package only to reach params
            if (ROOT.parent / Path(*target.split("."))).with_suffix(".py").exists() or \
                    (ROOT.parent / Path(*target.split("."))).is_dir():
                t = layer_of(target)
                if t is not None and t > own:
                    bad.append(f"{name} (layer {own}) imports {target} (layer {t})")
    assert not bad, "\n".join(bad)
