"""Parameter settings for sweeps: `--set material.youngs_modulus=1e9,3e9` on the command line
becomes a parameter path and its values; a point of the sweep (one value per path) is applied to
a scene and its shot as new frozen dataclasses, so their own checks name a bad value.

A path starts with `shot.` (a `runner.Shot` field: frames, fps, dt, width, ...) or names a
`Scene` field, optionally after `scene.`, and goes down through dataclass fields:
`material.youngs_modulus`, `drag`, `twist`, `wind.turbulence`, `hair_interaction.friction` (a
Scene's flat option names stand for their place in its options: `drag` is `environment.drag`,
`twist` is `solver.twist`). A
per-strand list of materials takes the setting on every material.
"""

import ast
import dataclasses
import hashlib
import itertools
import re

_PATH = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$")
_WORD = re.compile(r"[A-Za-z_][A-Za-z0-9_-]*$")


def parse_setting(text: str) -> tuple:
    """'material.youngs_modulus=1e9,3e9' -> ('material.youngs_modulus', [1e9, 3e9]).

    Values are Python literals (numbers, True/False, quoted strings, tuples in parentheses such
    as (0,2,0)) or bare words (quasistatic); commas inside parentheses belong to the value.
    ValueError naming the parameter for a missing '=', a malformed path, an empty or unbalanced
    value list, or a value that is neither a literal nor a word."""
    if not isinstance(text, str) or "=" not in text:
        raise ValueError(f"--set must be PATH=VALUE[,VALUE...], got {text!r}")
    path, _, rest = text.partition("=")
    path = path.strip()
    if not _PATH.match(path):
        raise ValueError(f"--set {text!r}: {path!r} is not a parameter path (e.g. material.youngs_modulus)")
    if path.split(".")[0] == "shot" and path.count(".") != 1:
        raise ValueError(f"--set {text!r}: {path!r} must be shot.FIELD (e.g. shot.frames)")
    values = [_parse_value(path, item) for item in _split_top_level(path, rest)]
    return path, values


def _split_top_level(path, text):
    """Split at commas outside parentheses and brackets; ValueError for empty items or unbalanced."""
    items, depth, start = [], 0, 0
    for k, ch in enumerate(text):
        if ch in "([":
            depth += 1
        elif ch in ")]":
            depth -= 1
        if depth < 0:
            break
        if ch == "," and depth == 0:
            items.append(text[start:k])
            start = k + 1
    if depth != 0:
        raise ValueError(f"{path}: unbalanced parentheses in {text!r}")
    items.append(text[start:])
    items = [i.strip() for i in items]
    if not all(items):
        raise ValueError(f"{path}: empty value in {text!r} (values are separated by single commas)")
    return items


def _parse_value(path, item):
    try:
        return ast.literal_eval(item)
    except (ValueError, SyntaxError):
        if _WORD.match(item):
            return item
        raise ValueError(f"{path}: cannot read the value {item!r} (a number, a word, a quoted string "
                         f"or a tuple such as (0,2,0))") from None


def sweep_points(settings) -> list:
    """The cartesian product of [(path, values), ...] as dicts {path: value}, first path slowest.
    ValueError for a path given twice, or a value listed twice for one path (two values that print
    alike, 1e-4 and 0.0001, are one: they would share a run folder and its summary)."""
    paths = [p for p, _ in settings]
    twice = sorted({p for p in paths if paths.count(p) > 1})
    if twice:
        raise ValueError(f"--set {twice[0]} is given more than once (list its values in one --set)")
    for path, values in settings:
        shown = [format_value(v) for v in values]
        again = next((v for k, v in enumerate(shown) if v in shown[:k]), None)
        if again is not None:
            raise ValueError(f"--set {path} lists the value {again} more than once (as written in folder "
                             f"names and tables): each value must be distinct")
    return [dict(zip(paths, combo)) for combo in itertools.product(*(v for _, v in settings))]


def apply_settings(scene, shot, point: dict) -> tuple:
    """(scene, shot) with every {path: value} of `point` set; ValueError naming the path for an
    unknown field, a part of the scene that is not there, or a value the dataclass refuses."""
    for path, value in point.items():
        parts = path.split(".")
        if parts[0] == "shot":
            shot = _replaced(shot, parts[1:], value, path)
        else:
            scene = _replaced(scene, parts[1:] if parts[0] == "scene" else parts, value, path)
    return scene, shot


def _replaced(obj, parts, value, path):
    """A copy of dataclass `obj` with the field chain `parts` set to value."""
    if isinstance(obj, (list, tuple)) and obj and all(dataclasses.is_dataclass(o) for o in obj):
        return type(obj)(_replaced(o, parts, value, path) for o in obj)  # per-strand materials
    if not dataclasses.is_dataclass(obj):
        raise ValueError(f"{path}: {type(obj).__name__} has no settable fields")
    aliases = getattr(type(obj), "FIELD_ALIASES", {})  # a Scene's flat names: drag -> environment.drag
    if parts and parts[0] in aliases:
        parts = aliases[parts[0]].split(".") + list(parts[1:])
    names = [f.name for f in dataclasses.fields(obj)]
    if not parts or parts[0] not in names:
        raise ValueError(f"{path}: unknown parameter; {type(obj).__name__} has {', '.join(names)}")
    name = parts[0]
    if len(parts) > 1:
        child = getattr(obj, name)
        if child is None:
            raise ValueError(f"{path}: this scene has no {name}")
        value = _replaced(child, parts[1:], value, path)
    try:
        return dataclasses.replace(obj, **{name: value})
    except (ValueError, TypeError) as err:
        raise ValueError(f"{path}={value!r}: {err}") from None


def format_value(value) -> str:
    """A value as written in tables and folder names: numbers by %g, tuples comma-joined."""
    if isinstance(value, bool) or isinstance(value, str):
        return str(value)
    if isinstance(value, (int, float)):
        return format(value, "g")
    if isinstance(value, (tuple, list)):
        return "(" + ",".join(format_value(v) for v in value) + ")"
    return str(value)


def point_name(point: dict) -> str:
    """A folder name for a point: 'material.youngs_modulus=1e+09_shot.frames=48' with characters
    outside [A-Za-z0-9.=+,()-] replaced; over 120 characters, cut and suffixed with a hash of the
    whole. The same settings always give the same name ('base' when there are none)."""
    text = "_".join(f"{p}={format_value(v)}" for p, v in point.items()) or "base"
    name = re.sub(r"[^A-Za-z0-9.=+,()_-]", "-", text)
    if len(name) > 120:
        name = name[:110] + "-" + hashlib.sha1(text.encode()).hexdigest()[:8]
    return name
