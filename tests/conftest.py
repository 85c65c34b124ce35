"""Taichi is initialised once for the whole suite: CPU, float64 (gradient checks need it).

float32 behaviour is tested in child processes (each initialises Taichi in float32).

Two tiers: `pytest -q` runs the fast tier (pyproject's addopts deselect `slow`), `pytest -q -m
slow` the rest. A test is slow when it carries `@pytest.mark.slow`, or when this hook recognises
it: it (or a fixture it uses, or a helper of its module it calls, at any depth) launches a
process (`subprocess`, `sys.executable`: each child starts Python and Taichi and compiles its
kernels from a cold start), runs a report's sweep or stability matrix, or runs a benchmark
experiment (a cosseratbench experiment, a timed rendering) (`SLOW_CALLS`, `SLOW_IMPORTS`)."""

import ast
import inspect
import os
from pathlib import Path

import pytest

# under pytest-xdist (`-n 2`) each worker keeps its own Taichi offline cache below the given one
# (or Taichi's default), and its child processes inherit it: two processes sharing one cache
# contend for its lock (Taichi warns "Lock ... ticache.lock failed" when it cleans up)
if os.environ.get("PYTEST_XDIST_WORKER"):
    _cache = os.environ.get("TI_OFFLINE_CACHE_FILE_PATH") or os.path.expanduser("~/.cache/taichi/ticache")
    os.environ["TI_OFFLINE_CACHE_FILE_PATH"] = os.path.join(_cache, os.environ["PYTEST_XDIST_WORKER"])

import taichi_hair as th  # noqa: E402  (after the cache path is chosen)

th.init(arch="cpu", precision="float64")

# a call to one of these names (a bare name or an attribute, e.g. `subprocess.run`,
# `reports.stability_report`) makes the calling function slow
SLOW_CALLS = {
    "Popen", "check_output", "check_call",  # a child process
    "run_cli", "kill_run_after",  # tests/helpers.py: `taichi-hair run` in a child process
    "accuracy_report", "stability_report", "run_stability_case",  # report sweeps and matrices
    "bench_rendering", "time_rendering",  # benchmark experiments
}
# a name imported from a module that is slow to call, whatever it is called locally
SLOW_IMPORTS = {
    ("cosseratbench.experiment", "run"),  # a whole cosseratbench experiment (a benchmark experiment)
    ("helpers", "run_cli"), ("helpers", "kill_run_after"),
}
# these attribute owners make any call through them slow (`subprocess.run`, `sys.executable`)
SLOW_OWNERS = {"subprocess"}
SLOW_NAMES = {"executable"}  # sys.executable: a command line that starts Python


def _launches(node, slow_calls) -> tuple:
    """(slow, names called) of a function's AST: slow when it calls a `slow_calls` name, anything
    of a SLOW_OWNERS module, or names sys.executable. A function defined inside it shadows a
    slow name of the module."""
    local = {sub.name for sub in ast.walk(node) if isinstance(sub, (ast.FunctionDef, ast.AsyncFunctionDef))}
    slow_calls = slow_calls - (local - {node.name})
    slow, called = False, set()
    for sub in ast.walk(node):
        if isinstance(sub, ast.Call):
            f = sub.func
            name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else None
            if name in slow_calls:
                slow = True
            if isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name) and f.value.id in SLOW_OWNERS:
                slow = True
            if name is not None:
                called.add(name)
        elif isinstance(sub, ast.Attribute) and sub.attr in SLOW_NAMES:
            slow = True
    return slow, called


_MODULES: dict = {}


def slow_functions(path: Path) -> set:
    """Names of a test module's functions (at any depth) that launch a process, sweep or
    benchmark, directly or through another function of the module (to a fixed point)."""
    if path not in _MODULES:
        tree = ast.parse(path.read_text(), filename=str(path))
        slow_calls = set(SLOW_CALLS)  # and their local names (`from helpers import run_cli as run`)
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                slow_calls |= {alias.asname or alias.name for alias in node.names
                               if (node.module, alias.name) in SLOW_IMPORTS or (alias.name in SLOW_CALLS and alias.asname)}
        facts = {}
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                slow, called = _launches(node, slow_calls)
                was = facts.get(node.name, (False, set()))
                facts[node.name] = (slow or was[0], called | was[1])
        slow = {name for name, (s, _) in facts.items() if s}
        while True:
            more = {name for name, (_, called) in facts.items() if called & slow} - slow
            if not more:
                break
            slow |= more
        _MODULES[path] = slow
    return _MODULES[path]


def recognised_slow(item) -> bool:
    """Whether the hook marks this test slow (module docstring)."""
    function = getattr(item, "function", None)
    if function is None:
        return False
    slow = slow_functions(Path(item.fspath))
    if function.__name__ in slow:
        return True
    for name in getattr(item, "fixturenames", ()):
        for definition in item._fixtureinfo.name2fixturedefs.get(name, ()):
            func = definition.func
            try:
                source = Path(inspect.getsourcefile(func))
            except TypeError:  # a builtin fixture
                continue
            if source.parent != Path(item.fspath).parent:
                continue  # pytest's own fixtures (tmp_path, monkeypatch, ...)
            if func.__name__ in slow_functions(source):
                return True
    return False


def pytest_collection_modifyitems(config, items):
    for item in items:
        if "slow" not in item.keywords and recognised_slow(item):
            item.add_marker(pytest.mark.slow)
