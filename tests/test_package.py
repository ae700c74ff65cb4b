"""The package's public face."""

from __future__ import annotations

import subprocess
import sys


def test_the_public_face_is_lazy():
    """``import fitstiff`` offers the verbs and nouns of the flow without importing JAX."""
    code = ("import sys, fitstiff; assert 'jax' not in sys.modules; "
            "names = ['load_logs', 'segment', 'build_model', 'fit', 'sample_posterior', "
            "'simulate', 'write_report', 'diagnose', 'Diagnosis', 'FitResult', 'Posterior']; "
            "assert all(callable(getattr(fitstiff, n)) for n in names)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def test_the_command_line_limits_malloc_arenas_unless_the_user_did():
    """Issue 13: glibc's per-thread arenas held 1.35 GB for the default posterior against
    0.89 GB with two; the CLI sets two before JAX starts, and leaves an explicit
    MALLOC_ARENA_MAX alone."""
    import os
    import subprocess
    import sys

    code = "from fitstiff.malloc import limit_arenas; print(limit_arenas())"
    env = {k: v for k, v in os.environ.items() if k != "MALLOC_ARENA_MAX"}
    ours = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=env, check=True).stdout.strip()
    theirs = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            env=env | {"MALLOC_ARENA_MAX": "4"}, check=True).stdout.strip()
    assert theirs == "False"
    assert ours == ("True" if sys.platform.startswith("linux") else "False")


#: fitstiff's layers, lowest first: a module imports only from its own layer or a lower one
#: (README, "Layout"); ``_testing`` (simulators and references for tests and benchmarks) sits
#: on top and nothing of the library imports it
LAYERS = (("", "__init__", "errors", "units", "_jax", "malloc", "interrupts", "data"),
          ("signal",), ("io",), ("segments",), ("physics",), ("inference",), ("diagnosis",), ("planning",),
          ("fleet",), ("present",), ("cli", "__main__"), ("_testing",))


def _imports():
    """(module, line, imported module) for every ``fitstiff`` import in the package, those
    inside functions included."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[1] / "fitstiff"
    for path in sorted(root.rglob("*.py")):
        name = ".".join(path.relative_to(root.parent).with_suffix("").parts)
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                targets = [node.module]
            elif isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            else:
                continue
            for target in targets:
                if target == "fitstiff" or target.startswith("fitstiff."):
                    yield name, node.lineno, target


def _layer(module: str) -> int:
    part = module.split(".")[1] if "." in module else ""
    return next(i for i, names in enumerate(LAYERS) if part in names)


def test_imports_only_point_down_the_layers():
    """The regrouping of issue 35: no module imports from a layer above its own."""
    upward = [f"{name}:{line} imports {target}" for name, line, target in _imports()
              if _layer(target) > _layer(name)]
    assert not upward, "\n".join(upward)


def test_no_cycle_among_module_level_imports():
    """Module-level imports form no cycle (a function may import lazily, e.g. to keep
    ``import fitstiff`` light)."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[1] / "fitstiff"
    graph: dict[str, set[str]] = {}
    modules = {".".join(p.relative_to(root.parent).with_suffix("").parts).removesuffix(
        ".__init__") for p in root.rglob("*.py")}
    for path in root.rglob("*.py"):
        name = ".".join(path.relative_to(root.parent).with_suffix("").parts).removesuffix(
            ".__init__")
        edges = graph.setdefault(name, set())
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module and \
                    node.module.startswith("fitstiff"):
                edges.add(node.module)
                edges.update(f"{node.module}.{a.name}" for a in node.names
                             if f"{node.module}.{a.name}" in modules)
    state: dict[str, int] = {}

    def visit(node, path):
        if state.get(node) == 1:
            raise AssertionError("import cycle: " + " -> ".join(path[path.index(node):] + [node]))
        if state.get(node) == 2:
            return
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if nxt in graph and nxt != node:
                visit(nxt, path + [node])
        state[node] = 2

    for node in sorted(graph):
        visit(node, [])
