"""The package's layering: data flows one way, and no module imports from a layer above it.

The layers are declared once, as import-linter contracts in ``pyproject.toml``
(``[tool.importlinter]``): the top-level modules and packages, and the layering inside each
package. These tests

- run ``lint-imports`` on the package and require every contract kept (grimp reads every static
  import form: ``import a.b``, ``import a.b as c``, ``from a import b``, ``from . import b``,
  ``from ..b import c``, imports inside functions and under ``TYPE_CHECKING``);
- scan the source for dynamic imports (``importlib.import_module``, ``__import__`` ...), which
  grimp cannot see: only the allow-listed ones may exist;
- require every module to be named by a contract's layer, so none escapes the contracts;
- check the README's Layout against the contract;
- plant an upward import of each form into a copy of the package and require each caught, so
  that none of the above passes vacuously.
"""

from __future__ import annotations

import ast
import functools
import json
import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

try:
    import tomllib
except ModuleNotFoundError:   # Python 3.10
    import tomli as tomllib

PROJECT = Path(__file__).resolve().parent.parent
PACKAGE = PROJECT / "apf_physics"
PYPROJECT = PROJECT / "pyproject.toml"
ROOT = "apf_physics"

LAZY_ALLOWED = {"torch", "cv2", "av", "ray", "numba"}
"""Third-party imports that may be deferred into a function (heavy, and not needed by every user;
numba's import takes half a second, paid where a compiled loop first runs: apf_physics.common.compiled)."""

DYNAMIC_ALLOWED = {
    ("apf_physics.cli", 'module = importlib.import_module(f"apf_physics.cli.{name}")'): "apf_physics.cli",
    ("apf_physics.planners", "return getattr(importlib.import_module(module), cls)(**kwargs)"): "apf_physics.planners",
    ("apf_physics.world.bundled", 'return Path(str(importlib.resources.files("apf_physics.worlds")))'): "apf_physics.worlds",
    ("apf_physics._compat", "module = importlib.import_module(self.new)"): "apf_physics",
}
"""(module, source line) of each dynamic import there may be → the package its targets lie in.

``cli`` loads the subcommand being run (:data:`apf_physics.cli.COMMANDS`), the only way ``cli``
reaches its subcommands (the contract keeps them independent of one another); ``planners`` loads the
planner named (:data:`apf_physics.planners.PLANNERS`), so that ``gradient`` never loads torch;
``bundled`` finds the world files' data package; ``_compat`` aliases the flat layout's old module
paths to their new homes (:data:`apf_physics._compat.MOVED`). Any other dynamic import fails
:func:`test_no_dynamic_imports_but_the_allowed`: import statically, or add it here with a reason."""

DYNAMIC_CALLS = {"import_module", "__import__", "reload", "module_from_spec", "spec_from_file_location",
                 "spec_from_loader", "exec_module", "load_module", "run_module", "run_path"}
"""Callables that import a module named at run time (importlib, imp, runpy, the builtin)."""
BUILTIN_CODE = {"exec", "eval"}
"""Builtins that run source text (which can import); only as bare names, not ``model.eval()``."""
MAY_IMPORT_DYNAMICALLY = re.compile(r"\b(%s|resources|importlib|imp|runpy)\b|(?<![.\w])(%s)\b"
                                    % ("|".join(sorted(DYNAMIC_CALLS)), "|".join(sorted(BUILTIN_CODE))))
"""Text every file with a dynamic import holds (a superset: only these files are parsed)."""
MAY_DEFER = re.compile(r"^[ \t]+(import|from)[ \t]", flags=re.M)
"""Text every file with an import inside a function holds (a superset: an indented import)."""


# -- the contracts -------------------------------------------------------------------------------

def contracts(pyproject: Path = PYPROJECT) -> list[dict]:
    config = tomllib.loads(pyproject.read_text(encoding="utf-8"))["tool"]["importlinter"]
    assert config["root_package"] == ROOT
    return config["contracts"]


def layer_groups(contract: dict) -> list[list[str]]:
    """The contract's layers, bottom first, each the list of its module names (container-prefixed)."""
    containers = contract.get("containers", [""])
    assert len(containers) == 1, "one container per contract: each package has its own layers"
    prefix = containers[0] + "." if containers[0] else ""
    return [[prefix + tail.strip().strip("()") for tail in re.split(r"[|:]", layer)]
            for layer in reversed(contract["layers"])]


def top_contract() -> dict:
    (top,) = [c for c in contracts() if c.get("containers") == [ROOT]]
    return top


@dataclass
class Lint:
    returncode: int
    output: str

    def status(self) -> dict[str, str]:
        """Contract name → ``KEPT`` or ``BROKEN``, from the summary."""
        return dict(re.findall(r"^(.+?) (KEPT|BROKEN)\b", self.output, flags=re.M))

    def caught(self, importer: str, imported: str, line: int) -> bool:
        """Whether a broken contract's report shows ``importer -> imported`` at ``line``
        (as a direct import or as a link of an indirect chain)."""
        pattern = rf"^[-\s]*{re.escape(importer)} -> {re.escape(imported)} \(([^)]*)\)"
        return any(f"l.{line}" in re.findall(r"l\.\d+", m) for m in re.findall(pattern, self.output, flags=re.M))


LINT_SCRIPT = """
import contextlib, importlib.util, io, json, os, sys
from importlinter import api  # noqa: F401 (configures import-linter)
from importlinter.application import use_cases
sys.path[:] = [p for p in sys.path if p not in ("", os.getcwd())]
config, roots, results = sys.argv[1], sys.argv[2:], []
for root in roots:
    sys.path.insert(0, root)
    importlib.invalidate_caches()
    origin = importlib.util.find_spec("apf_physics").origin   # where grimp reads the package
    assert origin == os.path.join(root, "apf_physics", "__init__.py"), (root, origin)
    with contextlib.redirect_stdout(io.StringIO()) as out:
        passed = use_cases.lint_imports(config_filename=config, cache_dir=None, no_logo=True)
    sys.path.remove(root)
    results.append((0 if passed else 1, out.getvalue()))
print(json.dumps(results))
"""
"""``lint-imports`` with the project's contracts on the package under each root in turn, in one
process (the graph builds in a fraction of a second; starting import-linter costs more)."""


def lint_all(roots: list[Path]) -> list[Lint]:
    """Run import-linter with the project's contracts on the package under each root: in a
    subprocess (this process may have imported the package from elsewhere), a few at once."""
    env = {**os.environ, "COLUMNS": "1000", "NO_COLOR": "1", "TERM": "dumb"}
    env.pop("PYTHONPATH", None)
    workers = max(1, min(len(roots), os.cpu_count() or 1, 4))
    chunks = [roots[i::workers] for i in range(workers)]
    running = [subprocess.Popen([sys.executable, "-c", LINT_SCRIPT, str(PYPROJECT), *map(str, chunk)], cwd=chunk[0],
                                env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for chunk in chunks]
    by_root = {}
    for chunk, process in zip(chunks, running):
        out, err = process.communicate(timeout=300)
        assert process.returncode == 0, err
        by_root.update({root: Lint(code, text) for root, (code, text) in zip(chunk, json.loads(out))})
    return [by_root[root] for root in roots]


def lint(root: Path) -> Lint:
    return lint_all([root])[0]


@pytest.fixture(scope="module")
def main_lint() -> Lint:
    return lint(PROJECT)


def test_contracts_kept(main_lint):
    names = [c["name"] for c in contracts()]
    assert len(names) >= 7 and len(set(names)) == len(names), "contracts with unique names"
    status = main_lint.status()
    assert main_lint.returncode == 0 and status == {name: "KEPT" for name in names}, main_lint.output
    analysed = int(re.search(r"Analyzed (\d+) files, (\d+) dependencies", main_lint.output).group(1))
    assert analysed == len(source_modules()), f"lint-imports saw {analysed} modules\n{main_lint.output}"


# -- every module has a layer ------------------------------------------------------------------

def source_modules(package: Path = PACKAGE) -> dict[str, Path]:
    """Every module of the package from its files: ``apf_physics.learning.config`` → its path."""
    found = {}
    for path in sorted(package.rglob("*.py")):
        parts = (ROOT,) + path.relative_to(package).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        found[".".join(parts)] = path
    return found


def test_every_module_in_a_layer():
    """Each module other than the root is named by a layer of its parent package's contract, so a
    new module (or package) cannot sit outside the contracts; each package is a contract's
    container, so its modules are layered too. ``exhaustive = true`` has import-linter check the
    same; this also catches a folder without ``__init__.py`` (which import-linter does not read)."""
    named: dict[str, list[str]] = {}
    containers = set()
    for contract in contracts():
        assert contract["type"] == "layers" and contract.get("exhaustive"), contract["name"]
        containers.update(contract["containers"])
        for group in layer_groups(contract):
            for module in group:
                named.setdefault(module, []).append(contract["name"])
    modules = source_modules()
    assert len(modules) > 50
    packages = {m for m, path in modules.items() if path.name == "__init__.py"}
    missing = sorted(m for m in modules if m != ROOT and m not in named)
    assert not missing, f"modules in no layer of pyproject.toml's [tool.importlinter] contracts: {missing}"
    twice = {m: names for m, names in named.items() if len(names) > 1}
    assert not twice, f"modules in more than one contract: {twice}"
    unlayered = sorted(packages - containers)
    assert not unlayered, f"packages without a contract for their own layers: {unlayered}"
    dirs = sorted(str(d.relative_to(PROJECT)) for d in PACKAGE.rglob("*")
                  if d.is_dir() and d.name != "__pycache__" and any(d.glob("*.py")) and not (d / "__init__.py").exists())
    assert not dirs, f"folders of Python files without __init__.py (outside the import graph): {dirs}"


@functools.lru_cache(maxsize=None)
def _parse(source: str) -> ast.Module:
    return ast.parse(source)


def parsed(path: Path, only: re.Pattern | None = None) -> tuple[ast.Module | None, list[str]]:
    """A module's syntax tree (parsed once per distinct text: the copies below share it) and lines;
    no tree when ``only`` is given and the text does not match it."""
    source = path.read_text(encoding="utf-8")
    if only is not None and not only.search(source):
        return None, []
    return _parse(source), source.splitlines()


# -- dynamic imports ---------------------------------------------------------------------------

def _name(node: ast.AST) -> str | None:
    return node.id if isinstance(node, ast.Name) else node.attr if isinstance(node, ast.Attribute) else None


def dynamic_imports(package: Path = PACKAGE) -> set[tuple[str, str]]:
    """(module, stripped source line) of every dynamic import, or reference to an importing callable."""
    found = set()
    for module, path in source_modules(package).items():
        tree, lines = parsed(path, MAY_IMPORT_DYNAMICALLY)
        for node in ast.walk(tree) if tree else ():
            hit = False
            if isinstance(node, ast.Call):
                name = _name(node.func)
                hit = (name in DYNAMIC_CALLS
                       or (isinstance(node.func, ast.Name) and name in BUILTIN_CODE)
                       # importlib.resources.files("pkg") imports pkg
                       or (name == "files" and isinstance(node.func, ast.Attribute) and _name(node.func.value) == "resources"))
            elif isinstance(node, (ast.Name, ast.Attribute)):
                hit = _name(node) in {"import_module", "__import__"}   # also held, not only called
            elif isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in {"importlib", "imp", "runpy"}:
                hit = any(alias.name in DYNAMIC_CALLS | {"files", "*"} for alias in node.names)
            if hit:
                found.add((module, lines[node.lineno - 1].strip()))
    return found


def test_no_dynamic_imports_but_the_allowed():
    found = dynamic_imports()
    unexpected = sorted(found - set(DYNAMIC_ALLOWED))
    assert not unexpected, ("dynamic imports, which import-linter cannot see (import statically, or allow "
                            f"them in tests/test_layers.py's DYNAMIC_ALLOWED with a reason): {unexpected}")
    gone = sorted(set(DYNAMIC_ALLOWED) - found)
    assert not gone, f"allowed dynamic imports no longer in the source (remove them from DYNAMIC_ALLOWED): {gone}"


def _registry(module: str, name: str):
    """A module-level dict literal, read from the source without importing."""
    tree, _ = parsed(source_modules()[module])
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(_name(t) == name for t in node.targets):
            return ast.literal_eval(node.value)
        if isinstance(node, ast.AnnAssign) and _name(node.target) == name:
            return ast.literal_eval(node.value)
    raise AssertionError(f"{module}.{name} not found")


def test_dynamic_import_targets_stay_in_their_package():
    """The registries the allowed dynamic imports read name modules where the allow-list says."""
    modules = source_modules()
    places = {module: place for (module, _), place in DYNAMIC_ALLOWED.items()}
    commands = [f"apf_physics.cli.{name}" for name in _registry("apf_physics.cli", "COMMANDS")]
    planners = [entry.split(":")[0] for entry, _ in _registry("apf_physics.planners", "PLANNERS").values()]
    for importer, targets in (("apf_physics.cli", commands), ("apf_physics.planners", planners)):
        assert targets
        for target in targets:
            assert target in modules and target.startswith(places[importer] + "."), (importer, target)


# -- imports deferred into functions ---------------------------------------------------------------

class _Deferred(ast.NodeVisitor):
    """Imports inside functions (at any depth), as ``(line, top-level name)``; ``.`` for relative."""

    def __init__(self):
        self.depth, self.found = 0, []

    def visit_FunctionDef(self, node):
        self.depth += 1
        self.generic_visit(node)
        self.depth -= 1

    visit_AsyncFunctionDef = visit_Lambda = visit_FunctionDef

    def visit_Import(self, node):
        if self.depth:
            self.found += [(node.lineno, alias.name.split(".")[0]) for alias in node.names]

    def visit_ImportFrom(self, node):
        if self.depth:
            self.found.append((node.lineno, node.module.split(".")[0] if node.level == 0 and node.module else "."))


def test_only_heavy_packages_imported_in_functions():
    """Imports sit at the top of a module, but for heavy optional third-party packages."""
    deferred = []
    for module, path in source_modules().items():
        tree, _ = parsed(path, MAY_DEFER)
        if tree is None:
            continue
        visitor = _Deferred()
        visitor.visit(tree)
        deferred += [f"{module} (l.{line}): {top}" for line, top in visitor.found if top not in LAZY_ALLOWED]
    assert not deferred, f"imports deferred into functions (only {sorted(LAZY_ALLOWED)} may be): {deferred}"


# -- the README ----------------------------------------------------------------------------------

def readme_layers() -> list[set[str]]:
    """The README's Layout chain, bottom first: each ``→``-separated step's backticked names."""
    text = (PROJECT / "README.md").read_text(encoding="utf-8")
    section = text.split("\n## Layout\n", 1)[1].split("\n## ", 1)[0]
    chains = [p for p in section.split("\n\n") if p.lstrip().startswith("`") and "→" in p]
    assert len(chains) == 1, "README's Layout: one paragraph `a`, `b` → `c` → ... lists the layers"
    chain = chains[0].split("\nBenchmarks are in", 1)[0]
    while re.search(r"\([^()]*\)", chain):
        chain = re.sub(r"\([^()]*\)", "", chain)   # descriptions, which may hold arrows and names
    return [{name.rstrip("/") for name in re.findall(r"`([^`]+)`", step)} for step in chain.split("→")]


def test_readme_layout_is_the_contract():
    contract = [{m.split(".", 1)[1] for m in group} for group in layer_groups(top_contract())]
    assert readme_layers() == contract, (
        "README's Layout and pyproject.toml's top-level import-linter contract differ\n"
        f"README:   {readme_layers()}\ncontract: {contract}")


# -- planted upward imports are caught -----------------------------------------------------------

PLANTED = [
    # (id, file, code appended, importer, imported, contract container)
    ("absolute", "common/geometry.py", "import apf_physics.cli", "apf_physics.common.geometry", "apf_physics.cli", ROOT),
    ("absolute-as", "world/field.py", "import apf_physics.sim.engine as engine", "apf_physics.world.field", "apf_physics.sim.engine", ROOT),
    ("from-root-module", "world/spatial.py", "from apf_physics import cli", "apf_physics.world.spatial", "apf_physics.cli", ROOT),
    ("from-root-name", "common/geometry.py", "from apf_physics import load_world", "apf_physics.common.geometry", ROOT, ROOT),
    ("relative", "errors.py", "from . import cli", "apf_physics.errors", "apf_physics.cli", ROOT),
    ("relative-parent", "envs/reward.py", "from ..cli import main", "apf_physics.envs.reward", "apf_physics.cli", ROOT),
    ("from-package-module", "world/core.py", "from apf_physics.learning import trainer", "apf_physics.world.core", "apf_physics.learning.trainer", ROOT),
    ("in-function", "world/obstacles.py", "def _planted():\n    from apf_physics.sim.engine import Stepper",
     "apf_physics.world.obstacles", "apf_physics.sim.engine", ROOT),
    ("type-checking", "world/core.py", "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from apf_physics.sim.engine import Stepper",
     "apf_physics.world.core", "apf_physics.sim.engine", ROOT),
    ("inside-package-type-checking", "sim/physics.py",
     "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from apf_physics.sim.engine import Stepper",
     "apf_physics.sim.physics", "apf_physics.sim.engine", "apf_physics.sim"),
    ("sibling", "sim/engine.py", "from apf_physics.render import drawing", "apf_physics.sim.engine", "apf_physics.render.drawing", ROOT),
    ("inside-package", "learning/config.py", "from apf_physics.learning import trainer", "apf_physics.learning.config", "apf_physics.learning.trainer", "apf_physics.learning"),
    ("inside-package-relative", "render/drawing.py", "from .page import PAGE", "apf_physics.render.drawing", "apf_physics.render.page", "apf_physics.render"),
    ("inside-package-sibling", "cli/eval.py", "from apf_physics.cli import demo", "apf_physics.cli.eval", "apf_physics.cli.demo", "apf_physics.cli"),
]
"""Each upward import is planted alone in its own copy of the package. The planted line is the
one the report must show (for ``from apf_physics import load_world``: the edge to the root,
which re-exports from above)."""

DYNAMIC_PLANTED = [
    ("common/geometry.py", 'import importlib\nimportlib.import_module("apf_physics.cli")'),
    ("errors.py", "from importlib import import_module"),
    ("world/spatial.py", '__import__("apf_physics.cli")'),
    ("learning/config.py", 'import importlib as il\n_load = il.import_module'),
    ("world/field.py", 'exec("import apf_physics.cli")'),
]


def copy_package(destination: Path) -> Path:
    """A copy of the package's Python files under ``destination`` (its root on PYTHONPATH)."""
    def not_python(folder, names):
        return [n for n in names if n == "__pycache__" or (Path(folder, n).is_file() and not n.endswith(".py"))]
    shutil.copytree(PACKAGE, destination / ROOT, ignore=not_python)
    return destination


def plant(root: Path, file: str, code: str) -> int:
    """Append ``code`` to ``file`` of the copy; the line number of its last line."""
    path = root / ROOT / file
    text = path.read_text(encoding="utf-8").rstrip("\n") + "\n\n" + code + "\n"
    path.write_text(text, encoding="utf-8")
    return len(text.splitlines())


def test_planted_upward_imports_are_caught(tmp_path):
    names = {c.get("containers", [""])[0]: c["name"] for c in contracts()}
    roots, lines = [copy_package(tmp_path / "clean")], []
    for form, file, code, *_ in PLANTED:
        root = copy_package(tmp_path / form)
        lines.append(plant(root, file, code))
        roots.append(root)
    clean, *results = lint_all(roots)
    assert clean.returncode == 0 and set(clean.status().values()) == {"KEPT"}, f"the unchanged copy:\n{clean.output}"
    missed = []
    for (form, file, code, importer, imported, container), line, result in zip(PLANTED, lines, results):
        if not (result.returncode != 0 and result.status().get(names[container]) == "BROKEN"
                and result.caught(importer, imported, line)):
            missed.append(f"{form}: {code!r} in {file}\n{result.output}")
    assert not missed, "upward imports not caught:\n" + "\n".join(missed)


def test_planted_dynamic_imports_are_caught(tmp_path):
    root = copy_package(tmp_path)
    assert dynamic_imports(root / ROOT) == set(DYNAMIC_ALLOWED), "the unchanged copy"
    for file, code in DYNAMIC_PLANTED:
        plant(root, file, code)
    module = {file: ".".join((ROOT,) + Path(file).with_suffix("").parts) for file, _ in DYNAMIC_PLANTED}
    caught = {m for m, _ in dynamic_imports(root / ROOT) - set(DYNAMIC_ALLOWED)}
    assert caught == set(module.values())
    # Each form on its own: every planted line is reported.
    found = dynamic_imports(root / ROOT)
    for file, code in DYNAMIC_PLANTED:
        last = code.splitlines()[-1].strip()
        assert (module[file], last) in found, (file, code)
