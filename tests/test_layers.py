"""The layers point one way: no crate depends on a crate above it, the Python package imports
nothing from the checkout's ``baselines/`` (which the wheel does not ship), and the modules of
``equigym-envs`` form no import circle."""

from __future__ import annotations

import ast
import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Each workspace crate and the workspace crates it may depend on (only ones below it).
ALLOWED = {
    "equigym-envs": set(),
    "equigym-nn": set(),
    "equigym-wrappers": {"equigym-envs", "equigym-nn"},
    "equigym-agents": {"equigym-envs", "equigym-nn", "equigym-wrappers"},
    "equigym-python": {"equigym-envs", "equigym-nn", "equigym-wrappers", "equigym-agents"},
}


def workspace_dependencies(metadata: dict) -> dict[str, set[str]]:
    members = {p["name"] for p in metadata["packages"]}
    return {
        p["name"]: {d["name"] for d in p["dependencies"] if d["name"] in members and d.get("kind") != "dev"}
        for p in metadata["packages"]
    }


def upward(deps: dict[str, set[str]]) -> list[str]:
    """Dependencies that are not allowed (a crate above, or a crate the table does not know)."""
    bad = [f"{c} (not in the layer table)" for c in deps if c not in ALLOWED]
    bad += [f"{c} -> {d}" for c, ds in deps.items() if c in ALLOWED for d in sorted(ds - ALLOWED[c])]
    return bad


@pytest.mark.skipif(shutil.which("cargo") is None, reason="needs cargo")
def test_no_crate_depends_on_a_crate_above_it():
    out = subprocess.run(
        ["cargo", "metadata", "--format-version", "1", "--no-deps", "--offline"],
        cwd=ROOT,
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    deps = workspace_dependencies(json.loads(out))
    assert set(deps) == set(ALLOWED), deps
    assert upward(deps) == []
    # The check itself can fail: the kernel crate importing the agents would be caught.
    assert upward({**deps, "equigym-nn": {"equigym-agents"}}) == ["equigym-nn -> equigym-agents"]


def imported_modules(source: str) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
    return names


def test_the_package_imports_nothing_from_baselines():
    offenders = {
        str(p.relative_to(ROOT)): sorted(m for m in imported_modules(p.read_text()) if m.split(".")[0] == "baselines")
        for p in sorted((ROOT / "python" / "equigym").rglob("*.py"))
    }
    assert {k: v for k, v in offenders.items() if v} == {}
    assert imported_modules("def f():\n    from baselines.steer import run\n") == {"baselines.steer"}


def module_graph(src: Path) -> dict[str, set[str]]:
    """`crate::m` edges between the top-level modules of a crate's `src/` (comments ignored)."""
    graph = {}
    for f in sorted(src.iterdir()):
        name = f.stem if f.suffix == ".rs" else f.name
        if name in ("lib", "main"):
            continue
        files = [f] if f.suffix == ".rs" else sorted(f.rglob("*.rs"))
        # Code only: a doc link to another module is not a dependency.
        text = "\n".join(re.sub(r"//.*", "", x.read_text()) for x in files)
        graph[name] = set(re.findall(r"crate::([a-z_][a-z0-9_]*)", text)) - {name}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    found, state = [], {}

    def visit(node: str, path: list[str]) -> None:
        state[node] = "open"
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == "open":
                found.append(path[path.index(nxt) :] + [nxt])
            elif nxt not in state:
                visit(nxt, path + [nxt])
        state[node] = "done"

    for n in sorted(graph):
        if n not in state:
            visit(n, [n])
    return found


def test_the_env_crate_has_no_import_circle():
    assert cycles(module_graph(ROOT / "envs" / "src")) == []
    assert cycles({"env": {"options"}, "options": {"env"}}) == [["env", "options", "env"]]
