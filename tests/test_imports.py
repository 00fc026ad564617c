"""The modules of ``cfm_jax`` import each other one way: no import cycle, counting the
imports inside functions too (the source is read, not executed, so an import that only
runs when a function is called counts as much as one at the top), and no import from a
higher layer (:data:`LAYERS`: the folders, bottom up).

Modules are the files of the package (``tasks.legged`` is one); an import of a package's
module does not count as an import of the package's ``__init__``."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "cfm_jax"


def module_names(package: Path = PACKAGE) -> dict[str, Path]:
    """Dotted names relative to the package ("" for the package itself) to their files."""
    names = {}
    for path in sorted(package.rglob("*.py")):
        parts = list(path.relative_to(package).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        names[".".join(parts)] = path
    return names


def imports_of(path: Path, name: str, modules: set[str], top: str = "cfm_jax") -> set[str]:
    """The modules of the package that the source of ``path`` imports, wherever it does."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()

    def add(dotted: str, names=()) -> None:
        # dotted: relative to the package root; `from X import y` may name a module X.y.
        for alias in names:
            child = f"{dotted}.{alias}" if dotted else alias
            if child in modules:
                found.add(child)
                continue
            found.add(dotted)
        if not names:
            found.add(dotted)

    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name == top or alias.name.startswith(top + "."):
                    add(alias.name[len(top) + 1 :])
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: from . import x, from .y import z
                base = package.split(".") if package else []
                base = base[: len(base) - (node.level - 1)] if node.level > 1 else base
                dotted = ".".join(base + ([node.module] if node.module else []))
            elif node.module == top or (node.module or "").startswith(top + "."):
                dotted = node.module[len(top) + 1 :]
            else:
                continue
            add(dotted, [a.name for a in node.names])
    return {m for m in found if m in modules and m != name}


def graph(package: Path = PACKAGE) -> dict[str, set[str]]:
    names = module_names(package)
    return {name: imports_of(path, name, set(names)) for name, path in names.items()}


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module, or with a module that
    imports itself (Tarjan's algorithm), each sorted."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1 or v in edges.get(v, ()):
                found.append(sorted(component))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return found


def test_no_import_cycle_in_cfm_jax():
    found = cycles(graph())
    edges = graph()
    detail = ["; ".join(f"{m} -> {sorted(edges[m] & set(c))}" for m in c) for c in found]
    assert not found, "import cycles:\n" + "\n".join(detail)


# The layers, bottom up (docs/api/index.md): a module may import its own layer and those
# below. Private helpers and the config sit below every folder; the package itself, the
# command line and the Gymnasium environments above.
LAYERS = ("", "sim", "tasks", "learning", "analysis", "runs", "top")
TOP = {"", "cli", "envs"}


def layer(module: str) -> int:
    """The rank in :data:`LAYERS` of a dotted module name relative to the package."""
    if module in TOP:
        return LAYERS.index("top")
    first = module.split(".")[0]
    return LAYERS.index(first) if first in LAYERS else 0


def upward(edges: dict[str, set[str]]) -> list[str]:
    """Every import of a module from a higher layer, as ``"a -> b"`` (``import cfm_jax``
    itself is not one: the package runs before any of its modules)."""
    return sorted(f"{a} -> {b}" for a, bs in edges.items() for b in bs
                  if b and layer(b) > layer(a))  # fmt: skip


def test_no_import_from_a_higher_layer():
    edges = graph()
    assert {m.split(".")[0] for m in edges if "." in m} <= set(LAYERS), "a folder not in LAYERS"
    assert not upward(edges), "imports from a higher layer:\n" + "\n".join(upward(edges))


def test_the_layer_check_finds_an_upward_import():
    """Negative control: the robots importing the babbling (a task's initial data), as
    they did before the layers were folders, is caught; the babbling importing the robots
    is not."""
    edges = {"sim.robots": {"config", "tasks.babbling"}, "tasks.babbling": {"sim.robots"}}
    assert upward(edges) == ["sim.robots -> tasks.babbling"]
    assert layer("config") == 0 and layer("_xla") == 0 and layer("cli") == layer("") == 6


def test_the_checker_finds_cycles_through_function_level_and_relative_imports(tmp_path):
    """Negative control: a package whose cycle closes through an import inside a function,
    a relative import and a subpackage's module is caught; the same package without it is
    not."""
    package = tmp_path / "cfm_jax"
    (package / "sub").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "config.py").write_text("X = 1\n")
    (package / "a.py").write_text("from cfm_jax import config\nfrom cfm_jax.sub import b\n")
    (package / "sub" / "__init__.py").write_text("from . import b\n")
    (package / "sub" / "b.py").write_text(
        "import numpy as np\n\ndef f():\n    from ..a import config\n    return config\n"
    )
    edges = graph(package)
    assert edges["a"] == {"config", "sub.b"}
    assert edges["sub.b"] == {"a"}
    assert edges["sub"] == {"sub.b"}
    assert cycles(edges) == [["a", "sub.b"]]
    (package / "sub" / "b.py").write_text("import cfm_jax.config\n")
    assert cycles(graph(package)) == []
    assert graph(package)["sub.b"] == {"config"}


def test_every_subpackage_ships_in_the_wheel():
    """pyproject lists packages by hand; a new subpackage missing there would import from a
    checkout but not from ``pip install .`` (what CI and users run)."""
    import tomllib

    listed = set(
        tomllib.loads((PACKAGE.parent / "pyproject.toml").read_text())["tool"]["setuptools"][
            "packages"
        ]
    )
    found = {
        ".".join(("cfm_jax", *init.parent.relative_to(PACKAGE).parts))
        for init in PACKAGE.rglob("__init__.py")
    }
    assert found <= listed, f"packages missing from pyproject.toml: {sorted(found - listed)}"
