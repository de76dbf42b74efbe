"""The package layout follows the light: a subpackage imports only from those before it (and the shared infrastructure)."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "paintjax"
#: The stages in the order light travels; the pipeline and the CLI sit on top.
LAYERS = ("optics", "wave", "brdf", "microstructure", "instrument", "tracer", "inverse", "_pipeline", "cli")
#: Shared infrastructure any stage may use; it imports no stage.
INFRASTRUCTURE = ("_cache", "_io", "_progress", "_samples", "_validate")


def _layer(parts: list[str]) -> str | None:
    return parts[0] if parts and parts[0] in LAYERS + INFRASTRUCTURE else None


def imported_layers(path: Path) -> set[str]:
    """The top-level parts of paintjax that module `path` imports (relative or absolute)."""
    here = list(path.relative_to(PACKAGE).with_suffix("").parts)[:-1]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = here[: len(here) - (node.level - 1)] if node.level > 1 else here
                parts = base + (node.module.split(".") if node.module else [])
                if not parts:  # `from .. import name` at the top: the names are the parts
                    parts = [a.name for a in node.names]
            elif node.module and node.module.split(".")[0] == "paintjax":
                parts = node.module.split(".")[1:] or [a.name for a in node.names]
            else:
                continue
            for candidate in ([parts[0]] if parts else []):
                if _layer([candidate]):
                    found.add(candidate)
    return found


def test_imports_point_down_the_light_path():
    bad = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE)
        own = rel.parts[0] if len(rel.parts) > 1 else rel.stem
        if own not in LAYERS + INFRASTRUCTURE:
            continue  # paintjax/__init__.py and __main__.py sit above everything
        for other in imported_layers(path) - {own}:
            if own in INFRASTRUCTURE and other not in INFRASTRUCTURE:
                bad.append(f"{rel} (infrastructure) imports {other}")
            elif own in LAYERS and other in LAYERS and LAYERS.index(other) > LAYERS.index(own):
                bad.append(f"{rel} ({own}) imports {other}, which comes after it")
    assert bad == []


def test_modules_stay_small():
    """Files over about 500 lines are split along the concepts inside them."""
    long = {str(p.relative_to(PACKAGE)): n for p in PACKAGE.rglob("*.py") if (n := len(p.read_text().splitlines())) > 560}
    assert long == {}
