"""Benchmark: `render_paint` preview, 512×512 at 64 spp on Mitsuba's llvm_ad_rgb variant (the Python/Dr.Jit
car-paint plugin), against the same scene with Mitsuba's built-in C++ `roughplastic` BSDF as the floor.

After one warm-up render at 32×32 (plugin registration and the first kernel compilations), each is timed
twice at full size: cold (the first full-size render, which may still compile kernels for the new size)
and warm (the same render again). Dr.Jit also caches kernels on disk (~/.drjit), so "cold" in a second
process is warmer than in the first. Goal: ≤ 60 s for the preview on the 2-core CPU.

Prints one JSON line and writes benchmarks/output/render.json (atomic).
Usage: python benchmarks/render.py [--resolution 512] [--spp 64] [--variant llvm_ad_rgb]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from datetime import date
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")

from paintjax import atomic_write_json  # noqa: E402

GOAL_S = 60.0
#: A realistic silver in the documented exchange format of the car-paint BRDF (docs/appearance.md).
SILVER = {"format": "paintjax-car-paint-brdf", "version": 1, "coat_index": 1.5, "diffuse": 0.05,
          "lobes": [{"weight": 0.3, "roughness": 0.08, "f0": 0.9}, {"weight": 0.15, "roughness": 0.2, "f0": 0.9},
                    {"weight": 0.05, "roughness": 0.5, "f0": 0.9}]}
#: The floor: Mitsuba's C++ rough plastic (a rough dielectric coat over a diffuse base).
BUILTIN = {"type": "roughplastic", "distribution": "beckmann", "alpha": 0.1, "int_ior": 1.5,
           "diffuse_reflectance": {"type": "rgb", "value": [0.3, 0.3, 0.3]}}


def timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    args = ap.parse_args()

    from paintjax.render import render_paint, render_scene, require_mitsuba, sphere_scene

    try:
        require_mitsuba(args.variant)
    except (ImportError, ValueError) as err:
        print(f"render benchmark skipped: {err}", file=sys.stderr)
        return 0
    res, spp, variant = args.resolution, args.spp, args.variant
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "silver.png"
        warmup = timed(lambda: render_paint(SILVER, out, resolution=32, spp=4, variant=variant, progress=False))
        cold = render_paint(SILVER, out, resolution=res, spp=spp, variant=variant, progress=True).seconds
        warm = render_paint(SILVER, out, resolution=res, spp=spp, variant=variant, progress=True).seconds

    def builtin(r: int, s: int) -> None:
        render_scene(sphere_scene(BUILTIN, resolution=r, variant=variant), spp=s, variant=variant, desc="roughplastic")

    builtin_warmup = timed(lambda: builtin(32, 4))
    builtin_cold = timed(lambda: builtin(res, spp))
    builtin_warm = timed(lambda: builtin(res, spp))
    result = {
        "machine": f"{platform.machine()}, {os.cpu_count()} cores",
        "date": date.today().isoformat(),
        "variant": variant,
        "resolution": res,
        "spp": spp,
        "warmup_32px_s": warmup,
        "paint_cold_s": cold,
        "paint_warm_s": warm,
        "builtin_roughplastic_warmup_32px_s": builtin_warmup,
        "builtin_roughplastic_cold_s": builtin_cold,
        "builtin_roughplastic_warm_s": builtin_warm,
        "ratio_warm_to_builtin": warm / builtin_warm,
        "ratio_cold_to_builtin": cold / builtin_cold,
        "goal_s": GOAL_S,
        "meets_goal": bool(cold <= GOAL_S),
    }
    atomic_write_json(Path(__file__).parent / "output" / "render.json", result)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
