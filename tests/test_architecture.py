"""The layers of the code, checked from its imports and attribute accesses (no code is run).

* ``movers`` and ``adjoint`` import only tofsi's foundation (finite elements, quality,
  errors, linear algebra, configuration, the block protocol and the iteration helpers);
* the foundation imports nothing above it;
* the scene's configuration (settings, scene tables) imports no physics, objective or model;
* no module outside ``movers`` compares anything with a mover's name;
* no library module reads or writes an underscore attribute of another object.
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FOUNDATION = ("tofsi.fem", "tofsi.mesh.quality", "tofsi.core.errors", "tofsi.linalg", "tofsi.core.config",
              "tofsi.core.blocks", "tofsi.core.iteration", "tofsi.core.registry", "tofsi.core.kept")


def modules(*packages):
    for package in packages:
        for path in sorted((ROOT / package).rglob("*.py")):
            yield path, ast.parse(path.read_text(), str(path))


def imported(tree):
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for alias in node.names:                                # from tofsi.mesh import quality
                sub = f"{node.module}.{alias.name}"
                path = ROOT.joinpath(*sub.split("."))
                yield sub if path.with_suffix(".py").is_file() or path.is_dir() else node.module


def tofsi_imports(tree):
    return {m for m in imported(tree) if m == "tofsi" or m.startswith("tofsi.")}


def is_foundation(module: str) -> bool:
    return any(module == f or module.startswith(f + ".") for f in FOUNDATION)


@pytest.mark.parametrize("package", ["movers", "adjoint"])
def test_movers_and_adjoint_import_only_the_foundation(package):
    bad = {f"{path.relative_to(ROOT)}: {m}" for path, tree in modules(package)
           for m in tofsi_imports(tree) if not is_foundation(m)}
    assert not bad, sorted(bad)


def test_the_foundation_imports_nothing_above_it():
    paths = [ROOT / "tofsi" / "fem", ROOT / "tofsi" / "linalg"] + [ROOT.joinpath(*m.split(".")).with_suffix(".py")
                                                              for m in FOUNDATION if m.count(".") == 2]
    bad = set()
    for path in paths:
        for file in ([path] if path.is_file() else sorted(path.rglob("*.py"))):
            tree = ast.parse(file.read_text())
            bad |= {f"{file.relative_to(ROOT)}: {m}" for m in tofsi_imports(tree) if not is_foundation(m)}
            bad |= {f"{file.relative_to(ROOT)}: {m}" for m in imported(tree)
                    if m.split(".")[0] in ("movers", "adjoint")}
    assert not bad, sorted(bad)


def test_no_library_module_touches_another_objects_underscore_attribute():
    def own(value):
        if isinstance(value, ast.Name) and value.id in ("self", "cls"):
            return True
        return isinstance(value, ast.Call) and isinstance(value.func, ast.Name) and value.func.id == "super"
    hits = []
    for path, tree in modules("tofsi", "movers", "adjoint"):
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and node.attr.startswith("_")
                    and not node.attr.startswith("__") and not own(node.value)):
                hits.append(f"{path.relative_to(ROOT)}:{node.lineno}: .{node.attr}")
            elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                  and node.func.id in ("getattr", "setattr", "hasattr") and len(node.args) >= 2
                  and isinstance(node.args[1], ast.Constant) and isinstance(node.args[1].value, str)
                  and node.args[1].value.startswith("_") and not node.args[1].value.startswith("__")
                  and not own(node.args[0])):
                hits.append(f"{path.relative_to(ROOT)}:{node.lineno}: {node.func.id}({node.args[1].value!r})")
    assert not hits, hits


def test_the_configuration_imports_no_physics_objective_or_model():
    below = ("tofsi.physics", "tofsi.objectives", "tofsi.fields", "tofsi.coupling.coupled", "tofsi.optimization.problem")
    bad = set()
    for name in ("scene/settings", "scene/tables", "core/config"):
        path = ROOT / "tofsi" / f"{name}.py"
        bad |= {f"tofsi/{name}.py: {m}" for m in tofsi_imports(ast.parse(path.read_text()))
                if any(m == b or m.startswith(b + ".") for b in below)}
    assert not bad, sorted(bad)


def test_no_mover_name_outside_the_movers_package():
    """A mover's name in a comparison (``scene.mover.name == "spring"``) is a second list of
    movers: what a mover can do belongs to the mover (``Mover.kinks``, ``inversion_hint``)."""
    import movers
    names = set(movers.available())
    hits = []
    for path, tree in modules("tofsi", "adjoint"):
        for node in ast.walk(tree):
            if isinstance(node, ast.Compare):
                for side in (node.left, *node.comparators):
                    if isinstance(side, ast.Constant) and side.value in names:
                        hits.append(f"{path.relative_to(ROOT)}:{node.lineno}: {side.value!r}")
    assert not hits, hits
