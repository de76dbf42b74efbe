"""The documentation site (user guide pages and the API reference from the docstrings) builds with warnings as errors."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_docs_build_strict(tmp_path):
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")], cwd=ROOT,
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    api = (tmp_path / "site" / "api" / "index.html").read_text()
    for name in ("paintjax.simulate", "paintjax.wave.solve_profiles", "paintjax.brdf.TabulatedBRDF", "paintjax.tracer.trace",
                 "paintjax.inverse.fit_least_squares"):
        assert f'id="{name}"' in api, f"{name} missing from the API reference"
