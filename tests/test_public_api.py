"""Experiments, benchmarks and notebooks use only the public API (no `paintjax._…` module or `_name`)."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _sources():
    for folder in ("experiments", "benchmarks"):
        for path in sorted((ROOT / folder).glob("*.py")):
            yield path, path.read_text()
    for path in sorted((ROOT / "notebooks").glob("*.ipynb")):
        cells = json.loads(path.read_text())["cells"]
        code = "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "code")
        yield path, "\n".join(line for line in code.splitlines() if not line.lstrip().startswith(("%", "!")))


def private_imports(source: str) -> list[str]:
    """`paintjax` imports in `source` that reach a private module or a private name."""
    bad = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "paintjax":
            parts = node.module.split(".")
            names = [a.name for a in node.names]
            if any(p.startswith("_") for p in parts) or any(n.startswith("_") for n in names):
                bad.append(f"from {node.module} import {', '.join(names)}")
        elif isinstance(node, ast.Import):
            bad += [f"import {a.name}" for a in node.names if a.name.split(".")[0] == "paintjax" and any(p.startswith("_") for p in a.name.split("."))]
        elif isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__"):
            base = node.value
            while isinstance(base, ast.Attribute):
                base = base.value
            if isinstance(base, ast.Name) and base.id in ("paintjax", "pj"):
                bad.append(ast.unparse(node))
    return bad


def test_the_checker_catches_private_imports():
    assert private_imports("from paintjax._io import atomic_write_json") == ["from paintjax._io import atomic_write_json"]
    assert private_imports("from paintjax.tracer._trace import trace")
    assert private_imports("from paintjax.tracer import _seed_state")
    assert private_imports("import paintjax._cache")
    assert private_imports("import paintjax as pj\npj._pipeline.simulate")
    assert private_imports("from paintjax import simulate\nfrom paintjax.wave import solve_profiles\nimport paintjax as pj\npj.trace") == []


@pytest.mark.parametrize("path,source", list(_sources()), ids=lambda v: v.name if isinstance(v, Path) else "")
def test_uses_only_the_public_api(path, source):
    assert private_imports(source) == [], f"{path.relative_to(ROOT)} imports private paintjax names"
