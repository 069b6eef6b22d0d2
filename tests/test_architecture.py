"""The layers of the code, checked from its imports and attribute accesses (no code is run).

* the floor table of ``docs/design.md`` (section 3a, "Floors") lists every module once,
  every module it lists exists, no import runs up a floor and none closes a circle;
* no module outside ``movers`` compares anything with a mover's name;
* no library module reads or writes an underscore attribute of another object.
"""

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("tofsi", "movers", "adjoint")


def modules(*packages):
    for package in packages:
        for path in sorted((ROOT / package).rglob("*.py")):
            yield path, ast.parse(path.read_text(), str(path))


def module_file(name: str) -> Path | None:
    """The file of a dotted module name (a package: its ``__init__.py``), None if there is none."""
    path = ROOT.joinpath(*name.split("."))
    for file in (path.with_suffix(".py"), path / "__init__.py"):
        if file.is_file():
            return file
    return None


def imported(tree):
    """Dotted names of the modules a tree imports, at any depth (lazy imports count)."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for alias in node.names:                                # from tofsi.mesh import quality
                sub = f"{node.module}.{alias.name}"
                yield sub if module_file(sub) else node.module


def floor_table() -> dict[Path, tuple[int, str]]:
    """``{file: (floor number, floor name)}`` from the design's floor table: each row's listed
    modules and its package's ``__init__.py``."""
    text = (ROOT / "docs" / "design.md").read_text()
    table = text[text.index("**Floors.**"):]
    table = table[:table.index("\n\n", table.index("| floor |"))]
    files: dict[Path, tuple[int, str]] = {}
    for row in table.splitlines():
        cells = [c.strip() for c in row.strip().strip("|").split("|")]
        match = re.fullmatch(r"(\d+) (.+)", cells[0])
        if not match:
            continue                                                # the header and its rule
        floor = (int(match[1]), match[2])
        package = ROOT / cells[1].strip("`")
        for name in ["__init__", *re.findall(r"`(\w+)`", cells[2])]:
            file = package / f"{name}.py"
            assert file not in files, f"{file.relative_to(ROOT)} is listed twice in the floor table"
            files[file] = floor
    return files


FLOORS = floor_table()


def test_the_floor_table_lists_every_module_once():
    actual = {path for path, _ in modules(*PACKAGES)}
    unlisted = sorted(str(p.relative_to(ROOT)) for p in actual - set(FLOORS))
    missing = sorted(str(p.relative_to(ROOT)) for p in set(FLOORS) - actual)
    assert not unlisted, f"modules on no floor of docs/design.md: {unlisted}"
    assert not missing, f"listed in docs/design.md's floor table, but no such file: {missing}"


@pytest.mark.parametrize("floor", sorted(set(FLOORS.values())), ids=lambda f: f"{f[0]} {f[1]}")
def test_no_import_runs_up_a_floor_or_closes_a_circle(floor):
    """A module of this floor imports modules of its own floor or lower ones only, and the
    floor's own imports form no circle (with the floors' order, the whole graph has none)."""
    here = [file for file, f in FLOORS.items() if f == floor]
    up, within = [], {file: set() for file in here}
    for file in here:
        for name in imported(ast.parse(file.read_text())):
            target = module_file(name) if name.split(".")[0] in PACKAGES else None
            if target is None:
                continue
            if FLOORS[target][0] > floor[0]:
                up.append(f"{file.relative_to(ROOT)} -> {name} (floor {FLOORS[target][0]})")
            elif FLOORS[target] == floor and target != file:
                within[file].add(target)
    assert not up, up
    state: dict[Path, int] = {}                           # 1 on the path, 2 done

    def circle_from(file, path):
        state[file] = 1
        for nxt in sorted(within[file]):
            if state.get(nxt) == 1:
                return path + [nxt]
            if nxt not in state and (found := circle_from(nxt, path + [nxt])):
                return found
        state[file] = 2
        return None
    for file in here:
        if file not in state and (circle := circle_from(file, [file])):
            raise AssertionError("a circle: " + " -> ".join(str(p.relative_to(ROOT)) for p in circle))


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
