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


LAYERS = ["rods", "world", "solver", "hair", "app"]  # each imports only from those before it


def test_modules_live_in_their_layer():
    """The package shows the architecture: its folders are layers; only the package's entry
    points and three shared helpers sit at its top."""
    top = sorted(p.name for p in PACKAGE.glob("*.py"))
    assert top == ["__init__.py", "__main__.py", "progress.py", "runtime.py", "validation.py"]
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
