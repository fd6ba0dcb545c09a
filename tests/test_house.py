"""The rules of the house (docs/architecture.md), checked on the source tree.

- No module imports another module's leading-underscore name (``from jaxplan.x import _y``,
  ``from jaxplan import _x``, or ``module._y`` on an imported jaxplan module).
- Layers only import downward: ``core`` imports no other jaxplan package; the systems
  (``transport``, ``pusharound``, ``teams``) and ``physics`` never import each other's packages, the
  CLI, sweeps or tuning (tuning imports the systems it fits); ``fleet`` builds on ``transport``
  (and counts conflicts with the serial checker of ``reference``); nothing but the CLI imports
  ``jaxplan.cli``.
- Each package lists its public API in ``__all__``, every listed name exists, and the names users
  call are importable from ``jaxplan``.
- A module imports another package only through names in that package's ``__all__`` (or a
  subpackage's), never through its modules; ``experiments/`` obeys the same rule, and the private-name
  rule.
- ``reference/`` imports nothing from the kernels it checks (only itself), and production code
  imports nothing from ``reference/``.
"""
from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "jaxplan"
MODULES = sorted(PACKAGE.rglob("*.py"))
EXPERIMENTS = sorted((ROOT / "experiments").rglob("*.py"))


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _jaxplan_imports(tree: ast.AST):
    """``(lineno, module, name, alias)`` of every ``import``/``from ... import`` of a jaxplan module."""
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0 and \
                node.module.split(".")[0] == "jaxplan":
            for alias in node.names:
                yield node.lineno, node.module, alias.name, alias.asname or alias.name
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "jaxplan":
                    yield node.lineno, alias.name, None, alias.asname or alias.name


def _is_module(dotted: str) -> bool:
    path = PACKAGE.parent / Path(*dotted.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


@pytest.mark.parametrize("path", MODULES + EXPERIMENTS, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_private_name_crosses_a_module_boundary(path):
    tree = ast.parse(path.read_text())
    problems = []
    module_aliases = set()
    for line, module, name, alias in _jaxplan_imports(tree):
        if name is None:
            continue
        if name.startswith("_"):
            problems.append(f"line {line}: from {module} import {name}")
        if _is_module(f"{module}.{name}"):
            module_aliases.add(alias)
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and \
                node.value.id in module_aliases and node.attr.startswith("_") and not node.attr.startswith("__"):
            problems.append(f"line {node.lineno}: {node.value.id}.{node.attr}")
    assert not problems, f"{path.relative_to(PACKAGE.parent)} uses private names of other modules: {problems}"


# which top-level packages each package may import (besides itself and ``core``)
ALLOWED = {
    "core": set(),
    "physics": set(),
    "reference": set(),
    "transport": {"physics"},
    "pusharound": {"physics"},
    "teams": set(),
    "tune": {"transport", "pusharound"},   # fits the fabric's and the gap ranking's parameters
    "sweep": {"transport"},
    "fleet": {"transport"},
    "cli": {"transport", "pusharound", "teams", "physics", "sweep", "tune", "fleet"},
}


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_imports_go_down_the_layers(path):
    parts = _module_name(path).split(".")
    if len(parts) < 2:
        return   # jaxplan/__init__.py re-exports everything
    package = parts[1]
    allowed = ALLOWED[package] | {package, "core"}
    bad = []
    for line, module, name, _ in _jaxplan_imports(ast.parse(path.read_text())):
        target = module.split(".")
        top = target[1] if len(target) > 1 else (name or "")
        if top and top not in allowed and not (top.startswith("_") or top[0].isupper() or top == "__version__"):
            bad.append(f"line {line}: {module}{'.' + name if name else ''}")
    assert not bad, f"{path.relative_to(PACKAGE.parent)} imports upward or sideways: {bad}"


PACKAGES = sorted({_module_name(p) for p in MODULES if p.name == "__init__.py"})


@pytest.mark.parametrize("package", PACKAGES)
def test_each_package_lists_an_api_that_exists(package):
    mod = importlib.import_module(package)
    names = getattr(mod, "__all__", None)
    assert names, f"{package}/__init__.py has no __all__"
    missing = [n for n in names if not hasattr(mod, n)]
    assert not missing, f"{package}.__all__ lists names it does not define: {missing}"


USER_NAMES = ("build_fabric", "run_episode", "Scene", "FabricParams", "SpillParams", "EpisodeParams", "Fabric",
              "builtin_scene", "selective_rebuild", "select_routes", "plan_pushes", "PushScene", "nominal_scene",
              "run_sites", "simulate_site", "paper_scenario", "sweep", "tune")


@pytest.mark.parametrize("name", USER_NAMES)
def test_users_names_import_from_the_top(name):
    import jaxplan

    assert getattr(jaxplan, name) is not None
    assert name in jaxplan.__all__


def _owner(path: Path) -> str | None:
    """The top-level jaxplan package ``path`` belongs to; None for ``jaxplan/__init__.py`` and experiments."""
    parts = path.relative_to(ROOT).parts
    return parts[1] if parts[0] == "jaxplan" and len(parts) > 2 else None


def _public_names(package: str) -> set[str]:
    return set(getattr(importlib.import_module(package), "__all__", ()))


def _is_package(dotted: str) -> bool:
    return (ROOT / Path(*dotted.split(".")) / "__init__.py").is_file()


@pytest.mark.parametrize("path", [m for m in MODULES if _owner(m)] + EXPERIMENTS,
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_other_packages_are_imported_through_their_public_api(path):
    owner = _owner(path)
    bad = []
    for line, module, name, _ in _jaxplan_imports(ast.parse(path.read_text())):
        parts = module.split(".")
        if len(parts) > 1 and parts[1] == owner:
            continue
        shown = f"line {line}: {'from ' + module + ' import ' + name if name else 'import ' + module}"
        if not _is_package(module):
            bad.append(f"{shown} ({module} is a module, not a package: import from its package)")
        elif name is not None and name not in _public_names(module):
            bad.append(f"{shown} ({name} is not in {module}.__all__)")
    assert not bad, f"{path.relative_to(ROOT)} reaches past another package's public API: {bad}"


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_reference_and_production_code_stay_apart(path):
    in_reference = _owner(path) == "reference"
    bad = []
    for line, module, name, _ in _jaxplan_imports(ast.parse(path.read_text())):
        parts = module.split(".") + ([name] if name else [])
        imports_reference = len(parts) > 1 and parts[1] == "reference"
        if in_reference != imports_reference and _owner(path) is not None:
            bad.append(f"line {line}: {module}{'.' + name if name else ''}")
    what = "imports kernels it checks" if in_reference else "imports the serial references"
    assert not bad, f"{path.relative_to(ROOT)} {what}: {bad}"


def test_the_architecture_picture_is_current():
    """docs/architecture.md's package graph is what ``tools/import_graph.py`` finds in the tree."""
    import subprocess
    import sys

    run = subprocess.run([sys.executable, str(ROOT / "tools" / "import_graph.py"), "--check"],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stdout + run.stderr


SYSTEMS_WITH_SCENES = ("transport", "pusharound", "fleet", "teams")
SYSTEMS_WITH_PHYSICS = ("transport", "pusharound", "fleet")


@pytest.mark.parametrize("system", SYSTEMS_WITH_SCENES)
def test_scene_generators_have_one_name_in_every_system(system):
    importlib.import_module(f"jaxplan.{system}.generators")
    others = [p.name for p in (PACKAGE / system).glob("*.py") if p.stem in ("scenes", "scenarios", "sites", "scenario")]
    assert not others, f"jaxplan/{system}: scene generators live in generators.py, not {others}"


@pytest.mark.parametrize("system", SYSTEMS_WITH_PHYSICS)
def test_physics_checks_have_one_name_in_every_system(system):
    assert _is_module(f"jaxplan.{system}.physics"), f"jaxplan/{system}: its MuJoCo check is jaxplan.{system}.physics"


DOCS = sorted((ROOT / "docs").glob("*.md"))
_LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)\s]*)?\)")


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_the_readme_lists_every_doc(doc):
    assert f"](docs/{doc.name})" in (ROOT / "README.md").read_text(), f"README.md does not link docs/{doc.name}"


@pytest.mark.parametrize("page", [ROOT / "README.md", ROOT / "experiments" / "README.md", *DOCS],
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_point_at_files(page):
    broken = [target for target in _LINK.findall(page.read_text())
              if "://" not in target and not target.startswith("mailto:") and not (page.parent / target).exists()]
    assert not broken, f"{page.relative_to(ROOT)} links to missing files: {broken}"
