"""The package's layering: data flows one way, and no module imports from a layer above it.

world file → world → field and raster → physics → stepper → environment / planner →
trainer → commands, with the renderer taking snapshots. Read from the source with ``ast``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "apf_physics"

LAYERS = [
    ("errors", "geometry"),
    ("safefile",),
    ("mapfiles", "buckets"),
    ("obstacles",),
    ("spatial",),
    ("field",),
    ("world", "bundled"),
    ("worldfile",),
    ("search", "curriculum"),
    ("generate",),
    ("physics", "observation", "actions"),
    ("formation",),
    ("engine",),
    ("models", "render"),
    ("planners", "envs"),
    ("rollout",),
    ("evaluate", "worldsets"),
    ("benchmark",),
    ("campaign",),
    ("rl",),
    ("commands", "cli"),
]
"""Bottom to top. A module may import from its own group (the first part of its name) and from lower layers."""
LAYER = {group: level for level, groups in enumerate(LAYERS) for group in groups}
LAZY_ALLOWED = {"torch", "cv2", "av", "ray"}
"""Third-party imports that may be deferred into a function (heavy, and not needed by every user)."""


def modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        yield ".".join(parts), path


def group_of(name: str) -> str:
    return name.split(".")[0]


def imports(path: Path):
    """``(imported apf_physics module or top-level package, inside a function?)`` for every import."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    inside = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for child in ast.walk(node):
                if isinstance(child, (ast.Import, ast.ImportFrom)):
                    inside.add(id(child))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, id(node) in inside
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            if node.module == "apf_physics":   # from apf_physics import world, field ...
                for alias in node.names:
                    yield f"apf_physics.{alias.name}", id(node) in inside
            else:
                yield node.module, id(node) in inside


def test_every_module_has_a_layer():
    missing = sorted({group_of(name) for name, _ in modules() if name and group_of(name) not in LAYER})
    assert not missing, f"modules without a layer in tests/test_layers.py: {missing}"


@pytest.mark.parametrize("name, path", [m for m in modules() if m[0]], ids=lambda v: str(v) if isinstance(v, str) else "")
def test_imports_flow_one_way(name, path):
    mine = LAYER[group_of(name)]
    upward, deferred = [], []
    for imported, in_function in imports(path):
        top = imported.split(".")[0]
        if top == "apf_physics":
            rest = imported.split(".", 1)[1] if "." in imported else ""
            if not rest or rest == "__version__":
                continue
            other = group_of(rest)
            if other not in LAYER:
                continue   # a name, not a module (e.g. `from apf_physics import load_world`)
            if LAYER[other] > mine or (LAYER[other] == mine and other != group_of(name)):
                upward.append(rest)
            if in_function:
                deferred.append(rest)
        elif in_function and top not in LAZY_ALLOWED | {"__future__"}:
            deferred.append(imported)
    assert not upward, f"{name} imports from a layer above or beside it: {upward}"
    assert not deferred, f"{name} defers imports into functions (only {sorted(LAZY_ALLOWED)} may be): {deferred}"
