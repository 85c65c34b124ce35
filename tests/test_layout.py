"""The package boundary: physics never imports the renderer, the renderer never imports physics.
Read from the source (every import statement, at any depth), so a lazy import counts too."""

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "taichi_hair"
# the application layer (taichi_hair/app/): commands that simulate and then draw frames or plots
APP = PACKAGE / "app"


def imported_packages(path: Path) -> set:
    """Top-level names of every module `path` imports (relative imports count as its own)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def test_physics_modules_do_not_import_render():
    physics = [p for p in sorted(PACKAGE.rglob("*.py")) if APP not in p.parents and p.name != "__main__.py"]
    assert len(physics) > 20
    offenders = [p.name for p in physics if "render" in imported_packages(p)]
    assert offenders == []


def test_render_does_not_import_taichi_hair():
    modules = sorted((ROOT / "render").rglob("*.py"))
    assert len(modules) > 5
    offenders = [p.name for p in modules if "taichi_hair" in imported_packages(p)]
    assert offenders == []


def test_import_boundary_detects_an_offender(tmp_path):
    """The check itself can fail: a module with a lazy render import is caught."""
    module = tmp_path / "rod_like.py"
    module.write_text("def f():\n    from render.plot import loglog\n    return loglog\n")
    assert "render" in imported_packages(module)


def test_importing_the_package_and_its_commands_loads_no_renderer():
    """The renderer is imported only where frames or plots are made, so every command starts
    without it (cli imports every command's module)."""
    code = "import sys, taichi_hair, taichi_hair.app.cli; print('render' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "False"


LAYERS = ["rods", "world", "solver", "hair", "diff", "app"]  # each imports only from those before it


def test_modules_live_in_their_layer():
    """The package shows the architecture: its folders are layers; only the package's entry
    points and five shared helpers sit at its top."""
    top = sorted(p.name for p in PACKAGE.glob("*.py"))
    assert top == ["__init__.py", "__main__.py", "diskcache.py", "progress.py", "runtime.py", "source_positions.py",
                   "validation.py"]
    layers = sorted(p.name for p in PACKAGE.iterdir() if p.is_dir() and (p / "__init__.py").exists())
    assert layers == sorted(LAYERS)


def layers_imported(path: Path) -> set:
    """The layers (taichi_hair subpackages) a module inside a layer imports, lazily or not; a
    relative import is resolved from the module's own place, at any depth (solver/step/x.py's
    `from ...rods` is rods)."""
    found = set()
    try:
        parts = path.resolve().relative_to(PACKAGE).parts[:-1]  # the module's package below taichi_hair
    except ValueError:
        parts = ("layer",)  # a module outside the package: read as one inside a layer
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ImportFrom):
            if node.level and node.module:
                base = parts[: len(parts) - (node.level - 1)] if node.level - 1 <= len(parts) else ()
                target = base + tuple(node.module.split("."))
                if target:
                    found.add(target[0])
            elif node.level == 0 and node.module and node.module.startswith("taichi_hair."):
                found.add(node.module.split(".")[1])
    return found & set(LAYERS)


def test_layers_import_only_earlier_layers():
    bad = []
    for rank, layer in enumerate(LAYERS):
        for path in sorted((PACKAGE / layer).rglob("*.py")):
            later = layers_imported(path) - set(LAYERS[:rank + 1])
            bad += [f"{path.relative_to(PACKAGE)} imports {sorted(later)}"] if later else []
    assert bad == []


def test_layer_check_detects_an_offender(tmp_path):
    module = tmp_path / "rod_like.py"
    module.write_text("def f():\n    from ..solver.step import advance\n    return advance\n")
    assert layers_imported(module) == {"solver"}
    real = sorted((PACKAGE / "solver" / "step").glob("*.py"))  # a nested package's `from ...rods`
    assert real and any("rods" in layers_imported(p) for p in real)


# ---- the module import graph: no cycles, no private names across modules -------------------------
def module_name(path: Path, root: Path) -> str:
    """Dotted name of a source file under `root` (a package's __init__.py is the package)."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(path: Path, name: str) -> list:
    """(module, imported name or None) for every import statement in the file, at any depth
    (function-local imports count), relative imports resolved against the module `name`."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found += [(alias.name, None) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            module = node.module
            if node.level:
                base = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
                base = base[:len(base) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            found += [(module, alias.name) for alias in node.names]
    return found


def import_graph(root: Path, packages=("taichi_hair", "render")) -> tuple:
    """({module: set of modules it imports}, [(importer, module, private name)]) over the source
    files of `packages` under `root`. `from a import b` is an edge to a.b when that is a module,
    else to a; importing a.b does not count as importing a's __init__ (the re-exports there would
    make every module part of one cycle)."""
    files = {module_name(p, root): p for package in packages for p in sorted((root / package).rglob("*.py"))}
    graph, private = {}, []
    for name, path in files.items():
        edges = set()
        for module, item in imports_of(path, name):
            if item is not None and f"{module}.{item}" in files:
                edges.add(f"{module}.{item}")
            elif module in files:
                edges.add(module)
                if item is not None and item.startswith("_") and module != name:
                    private.append((name, module, item))
        graph[name] = edges - {name}
    return graph, private


def import_cycles(graph: dict) -> list:
    """The strongly connected components of more than one module (each holds a cycle), sorted;
    Tarjan's algorithm, iterative."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return sorted(found)


def test_no_import_cycles():
    """No module imports (at any depth, lazily or not) a module that imports it back."""
    graph, _ = import_graph(ROOT)
    assert len(graph) > 80 and "taichi_hair.app.runner" in graph["taichi_hair.app.cluster"]
    assert import_cycles(graph) == []


def test_no_private_names_imported_across_modules():
    """A name with a leading underscore is private to its module: what another module needs gets
    a public name (and a home where it belongs)."""
    _, private = import_graph(ROOT)
    assert [f"{importer} imports {name} from {module}" for importer, module, name in private] == []


def test_import_checks_detect_offenders(tmp_path):
    """The checks can fail: a cycle through a function-local import, a relative import from a
    package's __init__, and a private name taken from another module are all found."""
    package = tmp_path / "taichi_hair"
    (package / "sub").mkdir(parents=True)
    (tmp_path / "render").mkdir()
    (package / "__init__.py").write_text("from .a import f\n")
    (package / "a.py").write_text("from .sub.b import _g\n\ndef f():\n    return _g()\n")
    (package / "sub" / "__init__.py").write_text("from . import c\n")
    (package / "sub" / "b.py").write_text("def _g():\n    from ..a import f\n    return f\n")
    (package / "sub" / "c.py").write_text("from taichi_hair.sub import b\n")
    graph, private = import_graph(tmp_path)
    assert graph["taichi_hair.sub"] == {"taichi_hair.sub.c"}
    assert graph["taichi_hair.sub.c"] == {"taichi_hair.sub.b"}
    assert import_cycles(graph) == [["taichi_hair.a", "taichi_hair.sub.b"]]
    assert private == [("taichi_hair.a", "taichi_hair.sub.b", "_g")]
    (package / "sub" / "b.py").write_text("def _g():\n    return 1\n")
    assert import_cycles(import_graph(tmp_path)[0]) == []
