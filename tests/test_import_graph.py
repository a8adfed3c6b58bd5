"""The import graph of jerklab points one way: no cycle, no import from a lower layer to a higher one.

The graph is built from the source with :mod:`ast`, from every import statement, at module level
and inside functions (``import x``, ``from x import y``, ``from . import y``) and from
``importlib.import_module("jerklab....")`` / ``lazy_module("jerklab....")`` with a literal name,
so a deferred import cannot hide an edge. The layers (lowest first; docs/INTERFACES.md, "Layers"):

=======  ======================================================================================
core     law, paper, protocol, planner (and its kernel _onedof), plant, controller
models   sim, metrics, ident (module or package), shaping, piezo, hysteresis, fpga, multiaxis,
         tuning, peers
rig      rig and its subpackages
face     lab, plots, widgets, app, broker, cli, diagrams, wiring, __main__, anything new
=======  ======================================================================================

``jerklab/__init__.py``, ``_validate``, ``_lazy``, ``_vocab`` and ``resources`` are base
utilities that every layer may use. A module may import its own layer or a lower one, without
cycles. The one way up is a result's ``.plot()`` that hands the result to ``jerklab.plots`` by
one late import (as python-control's ``TimeResponseData.plot`` does); :data:`PLOT_HANDOFFS`
lists each by (module, function). Other function-local jerklab imports are allowed only where
:data:`LATE_IMPORTS` lists them with the reason.
"""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "jerklab"

from jerklab._layers import BASE, LAYER_NAMES, LAYERS  # noqa: E402  (the one table)

#: (module, function qualname) of every ``.plot()`` that hands its result to jerklab.plots
PLOT_HANDOFFS = {
    ("jerklab.sim", "SimResult.plot"),
    ("jerklab.ident.data", "IdentData.plot"),
    ("jerklab.ident.validate", "ResidualAnalysis.plot"),
    ("jerklab.ident.validate", "CompareResult.plot"),
    ("jerklab.ident.validate", "CompareResults.plot"),
    ("jerklab.rig.recording", "Recording.plot"),
    ("jerklab.rig.recording", "Recording.plot_comparison"),
    ("jerklab.shaping", "Tradeoff.plot"),
}

#: (module, function qualname) -> why the jerklab import stays inside the function
LATE_IMPORTS = {
    ("jerklab.rig", "_launch_simavr"): (
        "jerklab.rig.simavr through sys.modules, so that a test can swap in a stand-in launcher"
    ),
    ("jerklab.cli", "app"): "the command line loads only its subcommand (the rig takes ~1 s)",
    ("jerklab.cli", "rig"): "the command line loads only its subcommand (the rig takes ~1 s)",
}


def _top(module: str) -> str:
    """The first component under ``jerklab.`` ("" for the package itself)."""
    return module.split(".")[1] if "." in module else ""


class Import:
    """One import statement: ``source`` imports ``target`` (a jerklab module) in ``function``."""

    __slots__ = ("source", "target", "function", "line", "in_class")

    def __init__(self, source, target, function, line, in_class):
        self.source, self.target, self.function, self.line = source, target, function, line
        self.in_class = in_class

    def __repr__(self):
        where = f"{self.function}()" if self.function else "module level"
        return f"{self.source}:{self.line} ({where}) -> {self.target}"


def _imported_names(module: str, is_package: bool, tree: ast.AST):
    """(dotted name, function qualname or None, line, inside a class method) of every import."""
    out = []

    def visit(node, qual, func, in_class):
        for child in ast.iter_child_nodes(node):
            q, f, c = qual, func, in_class
            if isinstance(child, ast.ClassDef):
                q = f"{qual}.{child.name}" if qual else child.name
                c = True
            elif isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                q = f"{qual}.{child.name}" if qual else child.name
                f = q
            if isinstance(child, ast.Import):
                out.extend((a.name, func, child.lineno, in_class) for a in child.names)
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    base = module.split(".") if is_package else module.split(".")[:-1]
                    base = base[: len(base) - (child.level - 1)]
                    target = ".".join(base + ([child.module] if child.module else []))
                else:
                    target = child.module
                out.extend(
                    (f"{target}.{a.name}", func, child.lineno, in_class) for a in child.names
                )
            elif isinstance(child, ast.Call):
                fn = child.func
                name = fn.attr if isinstance(fn, ast.Attribute) else getattr(fn, "id", None)
                arg = child.args[0] if child.args else None
                if (
                    name in ("import_module", "lazy_module")
                    and isinstance(arg, ast.Constant)
                    and isinstance(arg.value, str)
                ):
                    out.append((arg.value, func, child.lineno, in_class))
            visit(child, q, f, c)

    visit(tree, "", None, False)
    return out


def build_graph(root: Path = PACKAGE):
    """``(modules, imports)``: every module of the package under ``root`` and every import of a
    module of it (a name imported from a module resolves to that module)."""
    top = root.parent
    modules = {}
    for p in sorted(root.rglob("*.py")):
        parts = list(p.relative_to(top).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        modules[".".join(parts)] = p
    imports = []
    for mod, path in modules.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        for name, func, line, in_class in _imported_names(mod, path.name == "__init__.py", tree):
            if name.split(".")[0] != root.name:
                continue
            target = name
            while target and target not in modules:
                target = target.rpartition(".")[0]
            if target and target != mod:
                imports.append(Import(mod, target, func, line, in_class))
    return modules, imports


def layer(module: str, layers=LAYERS, base=BASE):
    """The layer of a module (None for a base utility): its first component's layer."""
    if module in base:
        return None
    return layers.get(_top(module), "face")


def cycles(modules, imports):
    """The strongly connected components with more than one module (Tarjan), sorted."""
    graph = defaultdict(set)
    for i in imports:
        graph[i.source].add(i.target)
    index, low, stack, on, found = {}, {}, [], set(), []
    counter = [0]

    def strong(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(modules):
        if v not in index:
            strong(v)
    return sorted(found)


def upward(imports, layers=LAYERS, base=BASE, handoffs=PLOT_HANDOFFS, plots="jerklab.plots"):
    """Imports from a lower layer to a higher one that are not listed ``.plot()`` hand-offs."""
    rank = {name: k for k, name in enumerate(LAYER_NAMES)}
    bad = []
    for i in imports:
        a, b = layer(i.source, layers, base), layer(i.target, layers, base)
        if a is None or b is None or rank[a] >= rank[b]:
            continue
        if i.target == plots and (i.source, i.function) in handoffs:
            continue
        bad.append(i)
    return bad


def is_plot_handoff(i: Import, plots="jerklab.plots") -> bool:
    """A method named ``plot`` (or ``plot_...``) importing from jerklab.plots in its body."""
    name = (i.function or "").rpartition(".")[2]
    return i.target == plots and i.in_class and (name == "plot" or name.startswith("plot_"))


@pytest.fixture(scope="module")
def graph():
    return build_graph()


def test_the_graph_is_read(graph):
    """The builder sees the package: every module, and both kinds of import."""
    modules, imports = graph
    assert "jerklab.rig.client" in modules and "jerklab.lab.session" in modules
    assert any(i.function is None for i in imports)
    assert any(i.function is not None for i in imports)


def test_no_cycle(graph):
    assert cycles(*graph) == []


def test_no_upward_import(graph):
    bad = upward(graph[1])
    assert bad == [], "imports from a lower layer to a higher one:\n" + "\n".join(map(repr, bad))


def test_every_listed_handoff_is_a_plot_method_that_exists(graph):
    _, imports = graph
    seen = {(i.source, i.function): i for i in imports if i.target == "jerklab.plots"}
    for key in sorted(PLOT_HANDOFFS):
        assert key in seen, f"{key} is listed as a .plot() hand-off but imports nothing from plots"
        assert is_plot_handoff(seen[key]), f"{seen[key]!r} is not a .plot()-style hand-off"


def test_function_local_imports_are_listed(graph):
    """A jerklab import inside a function is a listed ``.plot()`` hand-off or a listed late
    import; any other hides an edge of the graph (and usually a cycle)."""
    _, imports = graph
    hidden = [
        i
        for i in imports
        if i.function is not None
        and (i.source, i.function) not in PLOT_HANDOFFS
        and (i.source, i.function) not in LATE_IMPORTS
    ]
    assert hidden == [], "unlisted function-local imports:\n" + "\n".join(map(repr, hidden))
    used = {(i.source, i.function) for i in imports if i.function}
    assert set(LATE_IMPORTS) <= used, set(LATE_IMPORTS) - used


# ---------------------------------------------------------------- the checker itself
def _synthetic(tmp_path, files):
    pkg = tmp_path / "jerklab"
    for name, text in files.items():
        p = pkg / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    return build_graph(pkg)


def test_checker_finds_a_cycle_hidden_in_a_function(tmp_path):
    modules, imports = _synthetic(
        tmp_path,
        {
            "__init__.py": "",
            "law.py": "def f():\n    from jerklab import plant\n",
            "plant.py": "from . import law\n",
            "planner.py": "import importlib\nM = importlib.import_module('jerklab.paper')\n",
            "paper.py": "from jerklab.planner import x\n",
        },
    )
    assert cycles(modules, imports) == [
        ["jerklab.law", "jerklab.plant"],
        ["jerklab.paper", "jerklab.planner"],
    ]


def test_checker_finds_an_upward_import_and_lets_a_listed_plot_through(tmp_path):
    modules, imports = _synthetic(
        tmp_path,
        {
            "__init__.py": "",
            "plots.py": "",
            "sim.py": (
                "class R:\n    def plot(self):\n        from jerklab.plots import p\n"
                "def helper():\n    from jerklab.plots import p\n"
            ),
            "rig/__init__.py": "",
            "rig/client.py": "def f():\n    from jerklab.lab import motors\n",
            "lab/__init__.py": "",
            "lab/motors.py": "from jerklab.rig import client\n",
            "law.py": "from jerklab import sim\n",
        },
    )
    assert cycles(modules, imports) == [["jerklab.lab.motors", "jerklab.rig.client"]]
    bad = {(i.source, i.function, i.target) for i in upward(imports)}
    # the listed hand-off SimResult.plot is not listed for R.plot: both sim imports count
    assert bad == {
        ("jerklab.sim", "R.plot", "jerklab.plots"),
        ("jerklab.sim", "helper", "jerklab.plots"),
        ("jerklab.rig.client", "f", "jerklab.lab.motors"),
        ("jerklab.law", None, "jerklab.sim"),
    }
    ok = upward(imports, handoffs={("jerklab.sim", "R.plot")})
    assert {(i.source, i.function) for i in ok} == {
        ("jerklab.sim", "helper"),
        ("jerklab.rig.client", "f"),
        ("jerklab.law", None),
    }
    plot = [i for i in imports if i.function == "R.plot"][0]
    helper = [i for i in imports if i.function == "helper"][0]
    assert is_plot_handoff(plot) and not is_plot_handoff(helper)


def test_layers_of_modules():
    assert layer("jerklab.rig.simavr.harness") == "rig"
    assert layer("jerklab.ident.arx") == "models"  # the package form of ident
    assert layer("jerklab.ident") == "models"
    assert layer("jerklab.lab.checks") == "face"
    assert layer("jerklab.something_new") == "face"
    assert layer("jerklab._vocab") is None
