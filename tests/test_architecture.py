"""The house's layering, read from the source: every import of ``l2e_studio`` goes down the layers
below (or stays within its own package or module), and no module imports itself back through others.

The layers, bottom to top, as the README's architecture section describes them: a new arrow that
runs back up (say, ``calibrate`` reaching for ``verdict``) fails here with the import named.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "l2e_studio"

#: bottom to top; a unit is a top-level module or package of l2e_studio ("l2e_studio": its __init__)
LAYERS = (
    ("l2e_studio", "camera", "scoring", "errors", "atomic", "cachedir", "verdict_check", "drawing", "places"),
    ("geometry", "compiled", "limits", "samples", "pool"),
    ("io", "synth", "checks"),
    ("scenes", "score_maps"),
    ("objective",),
    ("calibrate",),
    ("target", "peaks", "evaluate"),
    ("evidence",),
    ("pinning",),
    ("verdict",),
    ("target_verdict", "export"),
    ("qa",),
    ("app",),
    ("cli",),
    ("__main__",),
)
RANK = {unit: i for i, layer in enumerate(LAYERS) for unit in layer}


def _modules() -> dict[str, Path]:
    out = {}
    for f in ROOT.rglob("*.py"):
        parts = f.relative_to(ROOT.parent).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = f
    return out


MODULES = _modules()


def _imports(name: str, top_level_only: bool) -> list[tuple[str, int]]:
    """(imported l2e_studio module, line) of module ``name``; with ``top_level_only`` only the
    imports that run when it is imported (not those inside functions, nor ``if TYPE_CHECKING:``)."""
    path = MODULES[name]
    tree = ast.parse(path.read_text())
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    if top_level_only:  # also inside module-level if/try blocks
        nodes = [n for top in tree.body if not isinstance(top, (ast.FunctionDef, ast.ClassDef)) and not _type_checking(top)
                 for n in ast.walk(top)]
    else:
        nodes = list(ast.walk(tree))
    found = []
    for node in nodes:
        if isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            target = ".".join(base + ([node.module] if node.module else []))
            for alias in node.names:
                full = f"{target}.{alias.name}"
                found.append((full if full in MODULES else target, node.lineno))
        elif isinstance(node, ast.Import):
            found += [(a.name, node.lineno) for a in node.names]
    return [(m, line) for m, line in found if m in MODULES and m != name]


def _type_checking(node: ast.stmt) -> bool:
    return isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)


def _unit(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def test_every_unit_has_a_layer():
    missing = sorted({_unit(m) for m in MODULES} - set(RANK))
    assert not missing, f"give these a layer in LAYERS: {missing}"


@pytest.mark.parametrize("name", sorted(MODULES))
def test_imports_go_down_the_layers(name):
    up = [f"{name}:{line} imports {target} ({_unit(target)} is layer {RANK[_unit(target)]}, "
          f"{_unit(name)} layer {RANK[_unit(name)]})"
          for target, line in _imports(name, top_level_only=False)
          if _unit(target) != _unit(name) and RANK[_unit(target)] >= RANK[_unit(name)]]
    assert not up, "\n".join(up)


def test_no_import_cycle():
    """Module-level imports (what runs at import time) form no cycle, within packages too."""
    graph = {m: sorted({t for t, _ in _imports(m, top_level_only=True)}) for m in MODULES}
    state: dict[str, int] = {}  # 1: on the path, 2: done

    def visit(m: str, path: list[str]) -> None:
        state[m] = 1
        for t in graph[m]:
            if state.get(t) == 1:
                pytest.fail("import cycle: " + " -> ".join(path[path.index(t):] + [m, t]) if t in path
                            else f"import cycle through {m} -> {t}")
            if t not in state:
                visit(t, path + [m])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [])
