"""Imports point down the layers, and private names stay inside their package.

Layers, bottom to top (a package may import its own modules and any lower layer)::

    aerohrl's bottom modules (errors, atomic, task, hardware, cli_common, cli_types, cluster, config)
    sim
    worlds
    datagen
    envs
    algorithms
    planning
    eval | ipp          (beside each other: neither imports the other)
    top: aerohrl (the package itself), aerohrl.api, aerohrl.cli, aerohrl.runs, aerohrl.sweep,
         and every package's cli.py

Top modules are thin entry points: they may import from any layer. Every module is read
with ``ast`` (the code is never imported), including imports inside functions (a lazy
import is still a dependency); imports inside ``if TYPE_CHECKING:`` blocks are type hints
only and are skipped. ``from aerohrl import __version__`` (the package itself) is allowed
everywhere: Python runs ``aerohrl/__init__.py`` before any of its submodules anyway.

Private names: no module imports a name starting with ``_`` (nor a module whose name
does) from another package, nor reads one through a module it imported
(``reference._positive``), top modules included; within a package it is fine.
"""

from __future__ import annotations

import ast
import tomllib
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE_DIRS: dict[str, str] = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]

# the modules of the aerohrl package itself, by layer
BOTTOM = {
    "aerohrl.errors",
    "aerohrl.atomic",
    "aerohrl.task",
    "aerohrl.hardware",
    "aerohrl.cli_common",
    "aerohrl.cli_types",
    "aerohrl.cluster",
    "aerohrl.config",
}
TOP = {"aerohrl", "aerohrl.api", "aerohrl.cli", "aerohrl.runs", "aerohrl.sweep", "aerohrl.benchmark"}
# layer units bottom to top; units in one tuple share a rank and may not import each other
LAYERS: list[tuple[str, ...]] = [
    ("bottom",),
    ("aerohrl.sim",),
    ("aerohrl.worlds",),
    ("aerohrl.datagen",),
    ("aerohrl.envs",),
    ("aerohrl.algorithms",),
    ("aerohrl.planning",),
    ("aerohrl.eval", "aerohrl.ipp"),
]
RANK = {unit: i for i, units in enumerate(LAYERS) for unit in units}

# Known violations in files this change does not own, each with its reason. An entry that
# no longer occurs fails the test: delete it once the import is gone.
ALLOWED: dict[str, str] = {}


def _modules() -> dict[str, Path]:
    """Every module of every package in pyproject's package-dir, by dotted name."""
    out = {}
    for pkg, folder in PACKAGE_DIRS.items():
        for f in sorted((ROOT / folder).glob("*.py")):
            out[pkg if f.stem == "__init__" else f"{pkg}.{f.stem}"] = f
    return out


MODULES = _modules()
PACKAGES = set(PACKAGE_DIRS)


def package_of(module: str) -> str:
    """The package a module belongs to (a package's ``__init__`` belongs to itself)."""
    if module in PACKAGES:
        return module
    return module.rpartition(".")[0]


def unit_of(module: str) -> str:
    """The layer unit of a module: ``bottom``, ``top`` or its package."""
    pkg = package_of(module)
    if pkg != "aerohrl":
        return pkg
    if module in BOTTOM:
        return "bottom"
    if module in TOP:
        return "top"
    raise AssertionError(f"{module} has no layer: add it to BOTTOM or TOP in tests/test_layers.py")


def is_entry_point(module: str) -> bool:
    """Top modules and every package's ``cli.py`` may import from any layer."""
    return module in TOP or module.endswith(".cli")


@dataclass(frozen=True)
class Import:
    target: str  # the module imported from
    name: str | None  # the name imported from it (None: the module itself)
    line: int
    bound: str | None = None  # the local name a module is bound to (None: not a module, or not bound)


def _type_checking_only(tree: ast.Module) -> set[int]:
    """ids of the nodes inside ``if TYPE_CHECKING:`` blocks (type hints only, never executed)."""
    skip = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            skip.update(id(n) for b in node.body for n in ast.walk(b))
    return skip


def _is_module(name: str, known: set[str]) -> bool:
    return name in known or name in PACKAGES


def imports(module: str, source: str, known: set[str] | None = None) -> list[Import]:
    """The aerohrl imports of ``module`` (its source ``source``), lazy ones included,
    ``TYPE_CHECKING`` blocks skipped. ``from pkg import sub`` of a submodule is an import of
    ``pkg.sub``; ``known`` is the set of module names (default: the repository's)."""
    known = set(MODULES) if known is None else known
    tree = ast.parse(source)
    skip = _type_checking_only(tree)
    package = package_of(module)
    out = []
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name == "aerohrl" or a.name.startswith("aerohrl."):
                    out.append(Import(a.name, None, node.lineno, a.asname))
                    if a.asname is None:  # `import aerohrl.x.y` binds `aerohrl`
                        out.append(Import("aerohrl", None, node.lineno, "aerohrl"))
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                if node.level > 1:
                    base = base[: -(node.level - 1)]
                src = ".".join(base + ([node.module] if node.module else []))
            else:
                src = node.module or ""
            if not (src == "aerohrl" or src.startswith("aerohrl.")):
                continue
            for a in node.names:
                sub = f"{src}.{a.name}"
                if _is_module(sub, known):
                    out.append(Import(sub, None, node.lineno, a.asname or a.name))
                else:
                    out.append(Import(src, a.name, node.lineno))
    return out


def _private(part: str) -> bool:
    return part.startswith("_") and not (part.startswith("__") and part.endswith("__"))


def private_attributes(module: str, source: str, known: set[str] | None = None) -> list[tuple[str, int]]:
    """``(module.name, line)`` for every private attribute read through an imported module
    (``reference._positive`` after ``from aerohrl.datagen import reference``)."""
    known = set(MODULES) if known is None else known
    bound = {i.bound: i.target for i in imports(module, source, known) if i.bound}
    out = []
    for node in ast.walk(ast.parse(source)):
        if not (isinstance(node, ast.Attribute) and _private(node.attr)):
            continue
        chain, base = [], node.value
        while isinstance(base, ast.Attribute):
            chain.insert(0, base.attr)
            base = base.value
        if isinstance(base, ast.Name) and base.id in bound:
            target = ".".join([bound[base.id], *chain])
            if _is_module(target, known):
                out.append((f"{target}.{node.attr}", node.lineno))
    return out


def violations(module: str, source: str, known: set[str] | None = None) -> dict[str, str]:
    """``{"importer -> imported": why}`` for every import of ``module`` that points up (or
    sideways between eval and ipp), and every private name taken from another package."""
    known = set(MODULES) if known is None else known | {module}
    out = {}
    unit = unit_of(module)
    for imp in imports(module, source, known):
        what = imp.target + (f".{imp.name}" if imp.name else "")
        key = f"{module} -> {what}"
        target_pkg = package_of(imp.target) if imp.target in known or imp.target in PACKAGES else imp.target
        parts = imp.target.split(".") + ([imp.name] if imp.name else [])
        if target_pkg != package_of(module) and any(_private(p) for p in parts):
            out[key] = f"line {imp.line}: a private name of another package"
        if is_entry_point(module) or imp.target == "aerohrl":
            continue
        target_unit = unit_of(imp.target)
        if target_unit == unit:
            continue
        if target_unit == "top" or RANK[target_unit] >= RANK[unit]:
            rel = "beside" if target_unit != "top" and RANK[target_unit] == RANK[unit] else "above"
            out[f"{module} -> {imp.target}"] = f"line {imp.line}: {unit} imports {target_unit}, which is {rel} it"
    for name, line in private_attributes(module, source, known):
        if package_of(name.rpartition(".")[0]) != package_of(module):
            out[f"{module} -> {name}"] = f"line {line}: a private name of another package"
    return out


def all_violations() -> dict[str, str]:
    out = {}
    for module, path in MODULES.items():
        for key, why in violations(module, path.read_text()).items():
            out[key] = f"{path.relative_to(ROOT)} {why}"
    return out


# ----------------------------------------------------------------------------- the checker can fail

SYNTHETIC = set(MODULES) | {"aerohrl.datagen.fake", "aerohrl.eval.fake", "aerohrl.ipp.fake", "aerohrl.sim.fake"}


def test_checker_flags_an_upward_edge():
    v = violations("aerohrl.datagen.fake", "from aerohrl.eval.harness import evaluate_run\n", SYNTHETIC)
    assert (
        list(v) == ["aerohrl.datagen.fake -> aerohrl.eval.harness"]
        and "above" in v["aerohrl.datagen.fake -> aerohrl.eval.harness"]
    )
    lazy = "def f():\n    from aerohrl.planning import planner\n    return planner\n"
    assert list(violations("aerohrl.datagen.fake", lazy, SYNTHETIC)) == ["aerohrl.datagen.fake -> aerohrl.planning.planner"]
    assert list(violations("aerohrl.sim.fake", "from aerohrl import api, task\n", SYNTHETIC)) == [
        "aerohrl.sim.fake -> aerohrl.api"
    ]
    assert list(violations("aerohrl.sim.fake", "import aerohrl.sweep\n", SYNTHETIC)) == ["aerohrl.sim.fake -> aerohrl.sweep"]
    beside = violations("aerohrl.eval.fake", "from aerohrl.ipp.env import SearchEnv\n", SYNTHETIC)
    assert "beside" in beside["aerohrl.eval.fake -> aerohrl.ipp.env"]
    assert list(violations("aerohrl.ipp.fake", "from aerohrl.eval import tasks\n", SYNTHETIC)) == [
        "aerohrl.ipp.fake -> aerohrl.eval.tasks"
    ]


def test_checker_flags_a_private_import():
    src = "from aerohrl.eval.reproduce import _evaluated\n"
    assert list(violations("aerohrl.ipp.fake", src, SYNTHETIC)) == [
        "aerohrl.ipp.fake -> aerohrl.eval.reproduce._evaluated",
        "aerohrl.ipp.fake -> aerohrl.eval.reproduce",
    ]
    assert list(violations("aerohrl.cli", src, SYNTHETIC)) == [
        "aerohrl.cli -> aerohrl.eval.reproduce._evaluated"
    ]  # entry points too
    assert list(violations("aerohrl.eval.fake", "from ._x import y\n", SYNTHETIC | {"aerohrl.eval._x"})) == []  # own package
    attr = (
        "from aerohrl.datagen import reference\nimport aerohrl.sim.params\nimport aerohrl\nf = reference._positive\n"
        "g = aerohrl.sim.params._hidden\naerohrl._register_env()\nh = reference.positive\n"
    )
    assert list(violations("aerohrl.eval.fake", attr, SYNTHETIC)) == [
        "aerohrl.eval.fake -> aerohrl.datagen.reference._positive",
        "aerohrl.eval.fake -> aerohrl.sim.params._hidden",
        "aerohrl.eval.fake -> aerohrl._register_env",
    ]
    assert list(violations("aerohrl.datagen.fake", "from . import reference\nf = reference._positive\n", SYNTHETIC)) == []
    assert list(violations("aerohrl.eval.fake", "from aerohrl.eval.tasks import _check_n\n", SYNTHETIC)) == []


def test_checker_allows_what_the_layers_allow():
    ok = (
        "from aerohrl import task, __version__\nfrom aerohrl.errors import UserError\nimport aerohrl\n"
        "from aerohrl.sim import BatchedQuadrotor\nfrom . import tasks\nfrom .tasks import TASKS\n"
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from aerohrl.api import Run\n"
        "def f():\n    from aerohrl.envs.rollout import rollout\n    from aerohrl.planning.planner import Planner\n"
    )
    assert violations("aerohrl.eval.fake", ok, SYNTHETIC) == {}
    assert violations("aerohrl.datagen.cli", "from aerohrl.eval.harness import evaluate_run\n", SYNTHETIC) == {}


# ----------------------------------------------------------------------------- the repository


def test_every_package_has_a_layer():
    for pkg in PACKAGES - {"aerohrl"}:
        assert pkg in RANK, f"{pkg} (pyproject package-dir) has no layer in tests/test_layers.py"
    for module in MODULES:
        unit_of(module)  # every module of the aerohrl package itself is bottom or top


def test_imports_point_down_and_private_names_stay_private():
    found = all_violations()
    new = {k: v for k, v in found.items() if k not in ALLOWED}
    assert not new, "imports against the layers:\n" + "\n".join(f"  {k}  ({v})" for k, v in sorted(new.items()))
    stale = sorted(set(ALLOWED) - set(found))
    assert not stale, f"allow-listed imports that no longer occur (delete them from ALLOWED): {stale}"
