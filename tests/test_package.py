"""The package as a whole: imports flow one way, importing it changes nothing in the process."""

import ast
import os
import subprocess
import sys
from pathlib import Path

import jnds_deploy

PKG = Path(jnds_deploy.__file__).parent


def _module_name(path: Path) -> str:
    parts = path.relative_to(PKG.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph() -> dict[str, set[str]]:
    """{module: modules of the package it imports}, every import statement counted (those
    inside functions too: a cycle through a deferred import is still a knot)."""
    modules = {_module_name(p): p for p in PKG.rglob("*.py")}
    graph = {}
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        deps = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                base = package
                for _ in range(node.level - 1):
                    base = base.rpartition(".")[0]
                target = f"{base}.{node.module}" if node.level and node.module else (node.module or base)
                if not node.level and not target.startswith("jnds_deploy"):
                    continue
                # "from . import x" names a submodule when one exists
                for alias in node.names:
                    sub = f"{target}.{alias.name}"
                    deps.add(sub if sub in modules else target)
            elif isinstance(node, ast.Import):
                deps |= {a.name for a in node.names if a.name.startswith("jnds_deploy.")}
        graph[name] = {d for d in deps if d in modules and d != name}
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n):
        state[n] = 1
        stack.append(n)
        for d in sorted(graph[n]):
            if state.get(d) == 1:
                return stack[stack.index(d) :] + [d]
            if d not in state and (found := visit(d)):
                return found
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if n not in state and (found := visit(n)):
            return found
    return None


def test_no_import_cycle():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_cycle_finder_finds_a_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def test_import_has_no_process_wide_side_effects():
    """Importing the package and its runtime sets no environment variable and no logger level
    (the libraries it uses are imported first: opencv, for one, edits LD_LIBRARY_PATH)."""
    code = (
        "import os, logging, json, cv2, numba, onnxruntime, OpenEXR; "
        "before = dict(os.environ); lv = logging.getLogger().level; "
        "import jnds_deploy, jnds_deploy.io, jnds_deploy.runtime.pipeline, jnds_deploy.runtime.filters; "
        "print(json.dumps({'env': sorted(set(os.environ.items()) ^ set(before.items())), "
        "'level': logging.getLogger().level == lv}))"
    )
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    assert out.stdout.strip() == '{"env": [], "level": true}'


def test_layers_import_downwards():
    """The torch specification (model, filters) does not import the runtime it specifies,
    and the artifact format (artifacts) imports none of its writers (export, calibration)
    or readers (runtime): constants and functions they share live below them."""
    graph = import_graph()

    def reach(name: str) -> set[str]:
        seen, todo = set(), [name]
        while todo:
            for d in graph[todo.pop()] - seen:
                seen.add(d)
                todo.append(d)
        return seen

    for spec in ("jnds_deploy.model", "jnds_deploy.filter_spec"):
        assert not {m for m in reach(spec) if m.startswith("jnds_deploy.runtime")}, spec
    for fmt in ("jnds_deploy.artifacts", "jnds_deploy.artifacts.manifest", "jnds_deploy.artifacts.layouts"):
        assert not {
            m
            for m in reach(fmt)
            if m.startswith(("jnds_deploy.runtime", "jnds_deploy.calibration", "jnds_deploy.export"))
        }, fmt
