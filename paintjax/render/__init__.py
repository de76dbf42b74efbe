"""Rendering of fitted car paints in Mitsuba 3 (optional extra: `pip install paintjax[render]`).

In: a `CarPaintBRDF` (`paintjax.appearance`, or its exported JSON content). Out: images of the paint on
a sphere outdoors (`render_paint`, `render_comparison`: PNG or EXR files and the linear image), and
render-based checks of the Mitsuba plugin against the model: the five-angle L* read back from a flat
panel under a collimated beam (`closed_loop_lightness`) and the white-furnace albedo (`furnace_radiance`).

The Mitsuba BSDF plugin "paintjax_carpaint" (`bsdf_dict`) evaluates the model's formula with Dr.Jit,
importance-samples it and adds the clearcoat's mirror reflection. Mitsuba is imported only when a
function needs it (`require_mitsuba` imports it, sets the variant and registers the plugin), never on
import of this package. The LLVM variants ("llvm_ad_rgb") need Dr.Jit's LLVM backend with LLVM 17 or
newer (e.g. Debian's libllvm19; `require_mitsuba` says so when an older one is found); the default
variant (`default_variant`) is "llvm_ad_rgb" where that holds, else "scalar_rgb" (slow).
"""

from __future__ import annotations

from ._bsdf import PLUGIN_NAME, bsdf_dict, default_variant, mixture_weights, require_mitsuba
from ._render import (
    ClosedLoopResult,
    ComparisonResult,
    FurnaceResult,
    RenderResult,
    closed_loop_lightness,
    furnace_radiance,
    render_comparison,
    render_paint,
    render_scene,
    tone_map,
)
from ._scenes import environment_map, furnace_scene, paint_sphere_scene, panel_scene, sphere_scene, sun_direction

__all__ = [
    "PLUGIN_NAME",
    "ClosedLoopResult",
    "ComparisonResult",
    "FurnaceResult",
    "RenderResult",
    "bsdf_dict",
    "default_variant",
    "closed_loop_lightness",
    "environment_map",
    "furnace_radiance",
    "furnace_scene",
    "mixture_weights",
    "paint_sphere_scene",
    "panel_scene",
    "render_comparison",
    "render_paint",
    "render_scene",
    "require_mitsuba",
    "sphere_scene",
    "sun_direction",
    "tone_map",
]
