"""No import circle among the project's modules: a module that imports another, at its top or
inside a function, never ends up importing itself back (a circle works or fails depending on
which module a process imports first, and it ties two concerns together)."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
AGENTS = ROOT / "agents"
PACKAGES = (AGENTS / "a3c_runtime", AGENTS / "a3c_tools", ROOT / "catch_env")


def project_modules() -> dict[str, Path]:
    """Every module of agents/ (the packages a3c_runtime and a3c_tools, the scripts, chapter 8's
    scripts) and of catch_env, by its import name (a script by its file's stem, as
    a3c_tools.load_script names it)."""
    modules = {}
    for package in PACKAGES:
        for path in package.rglob("*.py"):
            parts = path.relative_to(package.parent).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            modules[name] = path
    for path in [*AGENTS.glob("*.py"), *(AGENTS / "future_work").glob("*.py")]:
        modules[path.stem] = path
    return modules


def imported_modules(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The project modules that `name` imports anywhere in its file (a `from package import
    submodule` names the submodule; a relative import is resolved against the package)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join([*anchor, base] if base else anchor)
            targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base
                       for alias in node.names]  # fmt: skip
        else:
            continue
        found.update(target for target in targets if target in modules and target != name)
    return found


def import_graph() -> dict[str, set[str]]:
    modules = project_modules()
    return {name: imported_modules(name, path, modules) for name, path in modules.items()}


def find_circle(graph: dict[str, set[str]]) -> list[str] | None:
    """One circle of the graph (its modules, the first repeated at the end), or None."""
    state: dict[str, str] = {}  # "open" while on the current path, "done" once explored

    def visit(node: str, path: list[str]) -> list[str] | None:
        state[node] = "open"
        for target in sorted(graph[node]):
            if state.get(target) == "open":
                return path[path.index(target) :] + [target]
            if target not in state and (circle := visit(target, [*path, target])):
                return circle
        state[node] = "done"
        return None

    for node in sorted(graph):
        if node not in state and (circle := visit(node, [node])):
            return circle
    return None


def test_no_import_circle_in_the_project():
    graph = import_graph()
    assert {"a3c_ff", "a3c_runtime.a3c", "a3c_tools.paired", "catch_env.wrappers"} <= set(graph)
    assert "a3c_tools.paired" in graph["a3c_tools.thesis_claims"]  # the graph sees imports
    assert "a3c_runtime.flags" in graph["a3c_runtime.a3c"]  # relative ones too
    circle = find_circle(graph)
    assert circle is None, f"import circle: {' -> '.join(circle)}"


def test_find_circle_finds_one_through_a_function_level_import(tmp_path):
    """The check itself: the circle issue 72 found (atari_report imports paired at its top,
    paired imports atari_report inside a function) is found, and a chain is not a circle."""
    tools = tmp_path / "a3c_tools"
    tools.mkdir()
    (tools / "__init__.py").write_text("")
    (tools / "paired.py").write_text(
        "def random_play():\n    from a3c_tools.atari_report import CONFIG\n"
    )
    (tools / "atari_report.py").write_text("from a3c_tools.paired import MIN_PAIRS\n")
    (tools / "compare.py").write_text("from . import paired\n")
    modules = {"a3c_tools": tools / "__init__.py"} | {
        f"a3c_tools.{name}": tools / f"{name}.py" for name in ("paired", "atari_report", "compare")
    }
    graph = {name: imported_modules(name, path, modules) for name, path in modules.items()}
    assert graph["a3c_tools.compare"] == {"a3c_tools.paired"}
    assert find_circle(graph) == ["a3c_tools.atari_report", "a3c_tools.paired",
                                  "a3c_tools.atari_report"]  # fmt: skip
    assert find_circle({"a": {"b"}, "b": {"c"}, "c": set()}) is None
