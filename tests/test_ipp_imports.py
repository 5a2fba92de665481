"""ipp/ has no import cycles; environments never import planners.

The graph includes imports inside functions (lazy imports would hide a cycle from a
plain ``import`` test), read from the source with ``ast``.
"""

import ast
import subprocess
import sys
from pathlib import Path

import aerohrl.ipp

PKG = Path(aerohrl.ipp.__file__).parent
MODULES = sorted(p.stem for p in PKG.glob("*.py") if p.stem != "__init__")
PLANNERS = {"baselines", "policy", "train", "bench", "cli"}
ENVS = {"env", "semantic_env", "scoring", "sensor", "world", "semantic", "lattice", "features", "factory", "flown", "gym_env"}


def _type_checking_only(tree: ast.Module) -> set[int]:
    """ids of the import nodes inside ``if TYPE_CHECKING:`` blocks: type hints only, never
    executed, so they cannot form an import cycle."""
    skip = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            skip.update(id(n) for b in node.body for n in ast.walk(b))
    return skip


def _edges(mod: str) -> set[str]:
    """ipp modules imported anywhere in ``mod`` (relative or absolute), but for type hints."""
    tree = ast.parse((PKG / f"{mod}.py").read_text())
    skip = _type_checking_only(tree)
    out = set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.ImportFrom):
            if node.level == 1:
                if node.module:
                    out.add(node.module.split(".")[0])
                else:
                    out.update(a.name for a in node.names)
            elif node.module and node.module.startswith("aerohrl.ipp."):
                out.add(node.module.split(".")[2])
        elif isinstance(node, ast.Import):
            out.update(a.name.split(".")[2] for a in node.names if a.name.startswith("aerohrl.ipp."))
    return {m for m in out if m in MODULES and m != mod}


GRAPH = {m: _edges(m) for m in MODULES}


def _find_cycle(graph):
    state, stack = {}, []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                return stack[stack.index(n) :] + [n]
            if n not in state:
                c = visit(n)
                if c:
                    return c
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state:
            c = visit(m)
            if c:
                return c
    return None


def test_graph_parser_sees_a_cycle():
    # the checker itself must be able to fail
    assert _find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _find_cycle({"a": {"b"}, "b": set()}) is None
    assert "env" in GRAPH["semantic_env"] and "scoring" in GRAPH["env"]


def test_no_import_cycle_in_ipp():
    assert _find_cycle(GRAPH) is None, f"import cycle: {' -> '.join(_find_cycle(GRAPH))}"


def test_environments_never_import_planners():
    for m in ENVS & set(MODULES):
        bad = GRAPH[m] & PLANNERS
        assert not bad, f"{m} imports planner modules {sorted(bad)}"


def test_each_module_imports_alone():
    """Each module imported first, in a fresh set of ipp modules (one interpreter: the
    third-party imports are shared, every aerohrl.ipp module is dropped in between)."""
    code = (
        "import importlib, sys\n"
        f"for m in {MODULES!r}:\n"
        "    for k in [k for k in sys.modules if k == 'aerohrl.ipp' or k.startswith('aerohrl.ipp.')]:\n"
        "        del sys.modules[k]\n"
        "    importlib.import_module('aerohrl.ipp.' + m)\n"
        "print('ok')\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr[-2000:]
