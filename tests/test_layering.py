"""The one-way layering of README's architecture, read from the code: every import of every module, those
inside functions included.

- `calib` imports nothing of ours;
- `scanners` (drivers, acquisition, the simulated rig) imports `calib` only;
- `stereodic`'s processing modules import `calib` only (and each other);
- `stereodic.cli`, `stereodic.bench`, `stereodic.demo`, `stereodic.workspace` (the browser workspace of
  `stereodic view`) and `stereodic.__main__` (the top layer) may import everything, and nothing below
  imports them;
- and no module imports, through any chain of imports, a module that imports it back (no circles).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("calib", "scanners", "stereodic")
TOP = ("stereodic.cli", "stereodic.bench", "stereodic.demo", "stereodic.workspace", "stereodic.__main__")


def _module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _within(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def _layer(module: str) -> str:
    if any(_within(module, t) for t in TOP):
        return "top"
    return module.split(".")[0]


# which of our packages (or the top layer) each layer may import
ALLOWED = {"calib": {"calib"}, "scanners": {"calib", "scanners"}, "stereodic": {"calib", "stereodic"},
           "top": {"calib", "scanners", "stereodic", "top"}}


def _imports(tree: ast.AST, module: str, is_package: bool) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in the tree, at any depth; relative imports resolved."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")
                base = base[:len(base) - node.level + (1 if is_package else 0)]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            # "from stereodic import cli" imports stereodic.cli
            out += [(node.lineno, f"{name}.{a.name}") for a in node.names] if name in PACKAGES else \
                [(node.lineno, name)]
    return out


def layering_violations(root: Path) -> list[str]:
    """One line per import against the rule: 'module (file:line) imports name: layer may not import it'."""
    found = []
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            module = _module_name(path, root)
            layer = _layer(module)
            tree = ast.parse(path.read_text(), str(path))
            for line, name in _imports(tree, module, path.name == "__init__.py"):
                if name.split(".")[0] not in PACKAGES:
                    continue                                # the standard library and third parties
                target = _layer(name)
                if target not in ALLOWED[layer]:
                    found.append(f"{module} ({path.relative_to(root)}:{line}) imports {name}: "
                                 f"{layer} may import only {', '.join(sorted(ALLOWED[layer]))}")
    return found


def _target(name: str, modules: set[str]) -> str | None:
    """The module of ours that an imported name loads: itself, or for `from pkg import obj` the package."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def import_circles(root: Path) -> list[str]:
    """One line per circle of imports between our modules (a strongly connected set of two or more
    modules, imports inside functions included): 'a -> b -> ... -> a'. A package's own `__init__` and
    the modules inside it are not a circle: importing a module runs its package first by design."""
    import graphlib
    paths = {_module_name(p, root): p for package in PACKAGES for p in sorted((root / package).rglob("*.py"))}
    modules = set(paths)
    graph = {}
    for module, path in paths.items():
        tree = ast.parse(path.read_text(), str(path))
        names = [name for _, name in _imports(tree, module, path.name == "__init__.py")]
        # "from package import module" imports that module
        names += [f"{node.module}.{a.name}" for node in ast.walk(tree)
                  if isinstance(node, ast.ImportFrom) and not node.level and node.module for a in node.names]
        targets = {_target(name, modules) for name in names}
        graph[module] = {t for t in targets if t and t != module and not _within(module, t)}
    circles = []
    while True:
        try:
            graphlib.TopologicalSorter(graph).prepare()
            return circles
        except graphlib.CycleError as exc:
            cycle = exc.args[1][::-1]                    # graphlib lists it against the imports' direction
            circles.append(" -> ".join(cycle))
            graph[cycle[0]].discard(cycle[1])            # break it, and look for the next one


def test_every_import_follows_the_layering():
    violations = layering_violations(ROOT)
    assert not violations, "imports against the layering:\n" + "\n".join(violations)


def test_a_wrong_import_is_caught_and_named(tmp_path):
    for package in PACKAGES:
        (tmp_path / package).mkdir()
        (tmp_path / package / "__init__.py").write_text("")
    (tmp_path / "calib" / "fine.py").write_text("import numpy\nfrom calib import errors\n")
    (tmp_path / "calib" / "upward.py").write_text("def f():\n    from stereodic.stereo.rig import build_rig\n")
    (tmp_path / "scanners" / "sideways.py").write_text("from . import fine\nimport stereodic.stereo.triangulate\n")
    (tmp_path / "stereodic" / "processing.py").write_text("from ..scanners import sim\nfrom . import rig\n")
    (tmp_path / "stereodic" / "lower.py").write_text("from stereodic import cli\n")
    (tmp_path / "stereodic" / "cli").mkdir()
    (tmp_path / "stereodic" / "cli" / "__init__.py").write_text("import scanners.sim\nfrom ..bench import x\n")
    found = layering_violations(tmp_path)
    assert len(found) == 4, found
    assert found[0].startswith("calib.upward (calib/upward.py:2) imports stereodic.stereo.rig: calib may import only calib")
    assert found[1].startswith("scanners.sideways (scanners/sideways.py:2) imports stereodic.stereo.triangulate")
    assert found[2].startswith("stereodic.lower (stereodic/lower.py:1) imports stereodic.cli: stereodic may")
    assert found[3].startswith("stereodic.processing (stereodic/processing.py:1) imports scanners")


def test_no_import_circles():
    circles = import_circles(ROOT)
    assert not circles, "modules that import each other:\n" + "\n".join(circles)


def test_an_import_circle_is_caught_and_named(tmp_path):
    (tmp_path / "calib").mkdir()
    (tmp_path / "calib" / "__init__.py").write_text("from calib.a import x\n")
    (tmp_path / "calib" / "a.py").write_text("from calib.b import y\n")
    (tmp_path / "calib" / "b.py").write_text("def f():\n    from calib.c import z\n")
    (tmp_path / "calib" / "c.py").write_text("import calib.a\n")
    (tmp_path / "calib" / "d.py").write_text("import calib.a\n")
    (tmp_path / "calib" / "e.py").write_text("def f():\n    from calib import g\n")
    (tmp_path / "calib" / "g.py").write_text("from calib.e import f\n")
    circles = import_circles(tmp_path)
    assert len(circles) == 2
    assert {c.split(" -> ")[0] for c in circles} <= {"calib.a", "calib.b", "calib.c", "calib.e", "calib.g"}
    assert any(set(c.split(" -> ")) == {"calib.a", "calib.b", "calib.c"} for c in circles)
    assert any(set(c.split(" -> ")) == {"calib.e", "calib.g"} for c in circles)     # "from calib import g"
