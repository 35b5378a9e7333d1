"""The package layout holds: no import circle between the files of ``src/openemt`` and no package
importing a package above it in the declared order (README.md, "Architecture"). Imports inside
functions count too: a lazy import is still a dependency."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import openemt

SRC = Path(openemt.__file__).resolve().parent
README = SRC.parents[1] / "README.md"


def _module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(root: Path = SRC) -> dict[str, set[str]]:
    """Module -> the modules of the package at ``root`` it imports (``from x import name``
    counts as importing ``x.name`` when that is a module, else ``x``)."""
    modules = {_module_name(p, root): p for p in root.rglob("*.py")}
    graph = {}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        deps = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[:len(package.split(".")) - node.level + 1]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                for alias in node.names:
                    sub = f"{target}.{alias.name}"
                    deps.add(sub if sub in modules else target)
            elif isinstance(node, ast.Import):
                deps.update(a.name for a in node.names)
            elif isinstance(node, ast.Assign) and isinstance(node.value, ast.Dict) and \
                    [getattr(t, "id", None) for t in node.targets] == ["_SOURCES"]:
                # a lazy package's table (openemt._lazy): module -> the names it provides
                for key in node.value.keys:
                    rel = key.value
                    level = len(rel) - len(rel.lstrip("."))
                    base = package.split(".")[:len(package.split(".")) - level + 1]
                    deps.add(".".join(base + [rel.lstrip(".")]))
        graph[name] = {d for d in deps if d in modules and d != name}
    return graph


def _cycles(graph) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
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
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def _declared_order() -> list[str]:
    """The packages of README.md's architecture table, lowest layer first."""
    text = README.read_text(encoding="utf-8")
    table = text.split("## Architecture", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"^\| `openemt\.(\w+)` \|", table, flags=re.M)


def _package(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def test_no_import_circles_between_files():
    assert _cycles(_imports()) == []


def test_every_package_is_in_the_declared_order():
    order = _declared_order()
    packages = {p.name for p in SRC.iterdir() if (p / "__init__.py").is_file()}
    assert sorted(order) == sorted(packages), "README's architecture table vs src/openemt"
    assert set(openemt.SUBPACKAGES) == packages - {"cli"}


def test_no_package_imports_a_package_above_it():
    order = _declared_order()
    rank = {p: k for k, p in enumerate(order)}
    upward = sorted({(_package(a), _package(b)) for a, deps in _imports().items() for b in deps
                     if _package(a) in rank and _package(b) in rank
                     and rank[_package(b)] > rank[_package(a)]})
    assert upward == []


def test_the_checks_see_cycles_and_lazy_relative_imports(tmp_path):
    """The graph code finds a circle, and reads relative, absolute and function-level imports
    (so the tests above are not vacuous)."""
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("from .sub import low\n")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "low.py").write_text("def f():\n    from ..top import g\n    return g\n")
    (pkg / "top.py").write_text("import pkg.sub.low\n\ndef g():\n    pass\n")
    graph = _imports(pkg)
    assert graph["pkg.sub.low"] == {"pkg.top"}                 # lazy and relative
    assert graph["pkg.top"] == {"pkg.sub.low"}                 # absolute
    assert _cycles(graph) == [["pkg.sub.low", "pkg.top"]]
    assert "openemt.solve._prepared" in _imports()["openemt.solve._lm_solver"]
