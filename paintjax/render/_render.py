"""Renders and render-based checks of a `CarPaintBRDF` in Mitsuba 3 (the "paintjax_carpaint" plugin).

`render_paint` / `render_comparison`: the paint on a sphere outdoors (`_scenes` docstring has the light)
written as PNG or EXR. `closed_loop_lightness`: the five-angle reflectance and L* read back from a flat
panel under a collimated beam (it must equal the model's). `furnace_radiance`: the panel's directional
albedo under a uniform environment (exercises importance sampling and the pdf).

**Tone mapping** (PNG and the comparison figure): a fixed exposure (`EXPOSURE` = 1: linear radiance 1
is mapped like a white Lambertian surface under ≈ π of irradiance), then the extended Reinhard curve
y = x (1 + x / w²) / (1 + x) with white point w = `WHITE_POINT` (x ≥ w shows as full white), then the
sRGB transfer curve, 8 bits per channel. Fixed, so two paints rendered separately compare directly.
EXR files hold the linear radiance.
"""

from __future__ import annotations

import io
import math
import os
import sys
import time
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from .._io import atomic_path, atomic_savefig, atomic_write_bytes, nearest_existing
from ._bsdf import as_model, require_mitsuba
from ._scenes import furnace_scene, paint_sphere_scene, panel_scene

#: Tone-mapping exposure (linear radiance multiplier) and extended-Reinhard white point.
EXPOSURE = 1.0
WHITE_POINT = 4.0
#: Most Monte Carlo paths traced at once (memory bound of one pass).
MAX_LANES = 1 << 22


class _Fields:
    """Item access by field name too (`result["seconds"]`), as for a dict."""

    def __getitem__(self, key: str):
        if key not in self.keys():
            raise KeyError(key)
        return getattr(self, key)

    def keys(self) -> list[str]:
        return [f.name for f in fields(self)]


@dataclass(frozen=True)
class RenderResult(_Fields):
    """A render: `image` linear RGB radiance (height, width, 3) float32, the seconds the render took
    (scene load and passes, not the file write), samples per pixel, passes, and the file written."""

    image: np.ndarray
    seconds: float
    spp: int
    passes: int
    path: Path | None


@dataclass(frozen=True)
class ComparisonResult(_Fields):
    """Several paints rendered alike: one `RenderResult` per label, the seconds of all, spp, the figure written."""

    renders: dict
    seconds: float
    spp: int
    path: Path


@dataclass(frozen=True)
class ClosedLoopResult(_Fields):
    """Reflectance factors R = π L / (E cos θi) and L* at each aspecular angle, with Monte Carlo SEs."""

    aspecular_deg: np.ndarray
    detector_polar_deg: np.ndarray  # signed: negative on the illuminator side
    reflectance_factor: np.ndarray
    reflectance_factor_se: np.ndarray
    lightness: np.ndarray
    lightness_se: np.ndarray
    illumination_deg: float
    spp: int


@dataclass(frozen=True)
class FurnaceResult(_Fields):
    """Radiance of the panel under a uniform environment of radiance 1 (its directional albedo) and its SE."""

    theta_o_deg: float
    radiance: float
    se: float
    spp: int


# ---- argument checks -----------------------------------------------------------------------------------
def _check_int(name: str, value, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not lo <= int(value) <= hi:
        raise ValueError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}")
    return int(value)


def _check_out(out, suffixes=(".png", ".exr")) -> Path:
    try:
        path = Path(os.fspath(out))
    except TypeError:
        raise ValueError(f"out must be a file path ending in {' or '.join(suffixes)}, got {out!r}") from None
    if path.suffix.lower() not in suffixes:
        raise ValueError(f"out must end in {' or '.join(suffixes)}, got {str(path)!r}")
    if path.is_dir():
        raise ValueError(f"out is a folder, not a file: {str(path)!r}")
    base = nearest_existing(path.parent)
    if not base.is_dir() or not os.access(base, os.W_OK | os.X_OK):
        raise ValueError(f"out's folder cannot be written: {str(base)!r} is not a writable folder (for {str(path)!r})")
    return path


def _check_angle(name: str, value, lo: float, hi: float) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be an angle in [{lo:g}, {hi:g}] degrees, got {value!r}") from None
    if not (math.isfinite(v) and lo <= v <= hi):
        raise ValueError(f"{name} must be an angle in [{lo:g}, {hi:g}] degrees, got {value!r}")
    return v


def _check_sizes(resolution, spp, seed) -> tuple[int, int, int]:
    """resolution in [16, 4096], spp in [1, 65536], seed in [0, 2³² − 1] (ValueError naming the argument)."""
    return (_check_int("resolution", resolution, 16, 4096), _check_int("spp", spp, 1, 65536),
            _check_int("seed", seed, 0, (1 << 32) - 1))


# ---- rendering in passes -------------------------------------------------------------------------------
def _pass_seed(seed: int, k: int) -> int:
    return (seed * 1_000_003 + k) % (1 << 32)


def _render_passes(mi, scene, spp_per_pass: list[int], *, seed: int, sensor: int = 0, bar=None) -> list[np.ndarray]:
    """One image per pass (independent seeds); `bar` (tqdm) advances by each pass's spp."""
    images = []
    for k, spp in enumerate(spp_per_pass):
        images.append(np.array(mi.render(scene, sensor=sensor, spp=spp, seed=_pass_seed(seed, k)), dtype=np.float32))
        if bar is not None:
            bar.update(spp)
    return images


def _split(spp: int, lanes_per_spp: int) -> list[int]:
    """spp split into passes (at most 8 samples of spp/8 rounded up, and at most MAX_LANES paths, per pass)."""
    per = max(1, min(math.ceil(spp / 8), MAX_LANES // max(lanes_per_spp, 1)))
    full, rest = divmod(spp, per)
    return [per] * full + ([rest] if rest else [])


def render_scene(scene: dict, *, spp: int, seed: int = 0, variant: str | None = None, progress: bool = False,
                 desc: str = "render") -> np.ndarray:
    """Render a Mitsuba scene dict in passes (different seeds, averaged by spp), with a progress bar on stderr.

    Arguments:
        scene: a dict for `mi.load_dict` (e.g. `sphere_scene(...)`), built for `variant`.
        spp: samples per pixel in all, in [1, 65536].
        seed: base seed of the passes.
        variant: Mitsuba variant.
        progress: show a tqdm bar (one step per pass) on stderr.
        desc: the bar's label.

    Returns:
        The linear RGB image (height, width, 3) float32.
    """
    spp = _check_int("spp", spp, 1, 65536)
    seed = _check_int("seed", seed, 0, (1 << 32) - 1)
    mi = require_mitsuba(variant)
    loaded = mi.load_dict(scene)
    film = loaded.sensors()[0].film().size()
    passes = _split(spp, int(film[0]) * int(film[1]))
    from tqdm import tqdm

    with tqdm(total=spp, desc=desc, unit="spp", file=sys.stderr, disable=not progress, leave=True) as bar:
        images = _render_passes(mi, loaded, passes, seed=seed, bar=bar)
    return (sum(n * im for n, im in zip(passes, images)) / spp).astype(np.float32)


def tone_map(image: np.ndarray, exposure: float = EXPOSURE) -> np.ndarray:
    """Linear RGB radiance → 8-bit sRGB (module docstring: fixed exposure, extended Reinhard, sRGB)."""
    x = np.clip(np.nan_to_num(np.asarray(image, dtype=np.float64), nan=0.0, posinf=WHITE_POINT) * exposure, 0.0, None)
    y = np.clip(x * (1.0 + x / WHITE_POINT**2) / (1.0 + x), 0.0, 1.0)
    srgb = np.where(y <= 0.0031308, 12.92 * y, 1.055 * y ** (1.0 / 2.4) - 0.055)
    return np.round(255.0 * srgb).astype(np.uint8)


def _write_image(mi, image: np.ndarray, path: Path) -> None:
    """PNG (tone-mapped) or EXR (linear), written atomically (temporary file in the folder, then os.replace)."""
    if path.suffix.lower() == ".exr":
        with atomic_path(path) as tmp:
            mi.Bitmap(np.ascontiguousarray(image, dtype=np.float32)).write(str(tmp), mi.Bitmap.FileFormat.OpenEXR)
        return
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(tone_map(image), mode="RGB").save(buf, format="PNG")
    atomic_write_bytes(path, buf.getvalue())


def _sphere(model, resolution: int, spp: int, variant: str, seed: int, progress: bool, label: str = "") -> RenderResult:
    start = time.perf_counter()
    scene = paint_sphere_scene(model, resolution=resolution, variant=variant)
    image = render_scene(scene, spp=spp, seed=seed, variant=variant, progress=progress, desc=f"render {label}".rstrip())
    seconds = time.perf_counter() - start
    return RenderResult(image=image, seconds=seconds, spp=spp, passes=len(_split(spp, resolution * resolution)), path=None)


def render_paint(model, out, *, resolution: int = 512, spp: int = 64, variant: str | None = None, seed: int = 0,
                 progress: bool = True) -> RenderResult:
    """Render the paint on a unit sphere under the sky and the sun (`_scenes`) and write the image.

    Arguments:
        model: a `CarPaintBRDF` (or its `to_dict()` JSON content).
        out: the image file, `.png` (tone-mapped sRGB, module docstring) or `.exr` (linear); its folder
            is created if needed and must be writable; written atomically.
        resolution: square image side in pixels, in [16, 4096].
        spp: samples per pixel, in [1, 65536], rendered in passes of different seeds.
        variant: Mitsuba variant ("llvm_ad_rgb" on a CPU; "scalar_rgb" works but is slow).
        seed: base seed, in [0, 2³² − 1].
        progress: show one progress step per pass on stderr.

    Returns:
        `RenderResult` (linear image, seconds, spp, passes, path).
    """
    model = as_model(model)
    resolution, spp, seed = _check_sizes(resolution, spp, seed)
    path = _check_out(out)
    mi = require_mitsuba(variant)
    result = _sphere(model, resolution, spp, variant, seed, progress)
    _write_image(mi, result.image, path)
    return RenderResult(image=result.image, seconds=result.seconds, spp=spp, passes=result.passes, path=path)


def render_comparison(models: dict, out, **same) -> ComparisonResult:
    """Render several paints alike (`render_paint`'s keywords in `same`) and write them side by side with labels.

    Arguments:
        models: {label: `CarPaintBRDF`}, 1 to 12 paints.
        out: the `.png` figure (written atomically).
        same: resolution, spp, variant, seed, progress — as for `render_paint`, the same for every paint.

    Returns:
        `ComparisonResult`: `renders` {label: `RenderResult`, each with `path` = out}, total seconds, spp, path.
    """
    if not isinstance(models, dict) or not 1 <= len(models) <= 12 or not all(isinstance(k, str) for k in models):
        raise ValueError(f"models must be a dict of 1 to 12 paints keyed by label, got {type(models).__name__}")
    unknown = set(same) - {"resolution", "spp", "variant", "seed", "progress"}
    if unknown:
        raise ValueError(f"render_comparison takes resolution, spp, variant, seed, progress; got {sorted(unknown)}")
    resolution, spp, seed = _check_sizes(same.get("resolution", 512), same.get("spp", 64), same.get("seed", 0))
    variant, progress = same.get("variant"), bool(same.get("progress", True))
    path = _check_out(out, (".png",))
    paints = {label: as_model(m) for label, m in models.items()}
    require_mitsuba(variant)
    results = {label: _sphere(m, resolution, spp, variant, seed, progress, label) for label, m in paints.items()}

    from matplotlib.figure import Figure

    n, size = len(results), 3.0
    fig = Figure(figsize=(size * n, size + 0.4))
    for k, (label, result) in enumerate(results.items()):
        ax = fig.add_subplot(1, n, k + 1)
        ax.imshow(tone_map(result.image), interpolation="nearest")
        ax.set_title(label, fontsize=11)
        ax.set_axis_off()
    fig.subplots_adjust(left=0.01, right=0.99, bottom=0.01, top=0.9, wspace=0.03)
    atomic_savefig(fig, path, dpi=max(72, resolution / size), bbox_inches=None)
    renders = {label: RenderResult(r.image, r.seconds, r.spp, r.passes, path) for label, r in results.items()}
    return ComparisonResult(renders=renders, seconds=sum(r.seconds for r in renders.values()), spp=spp, path=path)


# ---- render-based checks -------------------------------------------------------------------------------
def closed_loop_lightness(model, aspecular_deg=(15.0, 25.0, 45.0, 75.0, 110.0), *, illumination_deg: float = 45.0,
                          spp: int = 64, passes: int = 4, variant: str | None = None, seed: int = 0) -> ClosedLoopResult:
    """Five-angle reflectance read back from a rendered flat panel (`panel_scene`): the closed loop.

    A collimated beam of irradiance E = 1 comes from the −x side at `illumination_deg`; a radiance meter
    per aspecular angle γ sits in the plane at the signed polar angle θi − γ (negative: illuminator side)
    and reads L; R = π L / (E cos θi) (the coat's mirror reflection is not seen off the specular direction).

    Arguments:
        model: a `CarPaintBRDF`.
        aspecular_deg: aspecular angles γ [deg] (as `ma98_geometry`).
        illumination_deg: illumination polar angle [deg].
        spp: paths per detector in all, in [passes, 65536]; split into `passes` equal passes.
        passes: independent passes, in [2, 64], whose spread gives the SE.
        variant, seed: Mitsuba variant and base seed.

    Returns:
        `ClosedLoopResult` (R and L* with standard errors from the passes).
    """
    from ..instrument._geometry import ma98_geometry
    from ..tracer._trace import lightness_with_se

    model = as_model(model)
    geometry = ma98_geometry(illumination_deg, aspecular_deg)  # ValueError naming the bad argument
    passes = _check_int("passes", passes, 2, 64)
    spp = _check_int("spp", spp, passes, 65536)
    seed = _check_int("seed", seed, 0, (1 << 32) - 1)
    theta_i = float(geometry.illumination_polar_deg)
    gamma = np.asarray(geometry.aspecular_deg, dtype=float)
    signed = theta_i - gamma
    mi = require_mitsuba(variant)
    scene = mi.load_dict(panel_scene(model, signed, illumination_deg=theta_i, irradiance=1.0, variant=variant))
    per = spp // passes
    R = np.empty((len(signed), passes))
    for k in range(len(signed)):
        images = _render_passes(mi, scene, [per] * passes, seed=seed + k, sensor=k)
        R[k] = [math.pi * float(np.mean(im)) / math.cos(math.radians(theta_i)) for im in images]
    mean, se = R.mean(axis=1), R.std(axis=1, ddof=1) / math.sqrt(passes)
    L, L_se = lightness_with_se(np.maximum(mean, 0.0), se)  # the tracer's delta-method L* SE
    return ClosedLoopResult(aspecular_deg=gamma, detector_polar_deg=signed, reflectance_factor=mean, reflectance_factor_se=se,
                            lightness=L, lightness_se=L_se, illumination_deg=theta_i, spp=per * passes)


def furnace_radiance(model, theta_o_deg: float, *, spp: int = 1 << 18, passes: int = 8, variant: str | None = None,
                     seed: int = 0) -> FurnaceResult:
    """Radiance of the flat panel seen from polar angle θo inside a uniform environment of radiance 1.

    That is the directional albedo ∫ f cosθ dω + R_coat(θo), estimated by one-bounce path tracing with
    emitter and BSDF sampling (MIS), so it checks the plugin's `sample`, `pdf` and delta reflection.

    Arguments:
        model: a `CarPaintBRDF`.
        theta_o_deg: viewing polar angle in [0, 85] degrees.
        spp: paths in all, in [passes, 2²⁴], split into `passes` equal passes.
        passes: independent passes, in [2, 64], whose spread gives the SE.
        variant, seed: Mitsuba variant and base seed.

    Returns:
        `FurnaceResult` (radiance, its SE, spp).
    """
    model = as_model(model)
    theta_o = _check_angle("theta_o_deg", theta_o_deg, 0.0, 85.0)
    passes = _check_int("passes", passes, 2, 64)
    spp = _check_int("spp", spp, passes, 1 << 24)
    seed = _check_int("seed", seed, 0, (1 << 32) - 1)
    mi = require_mitsuba(variant)
    scene = mi.load_dict(furnace_scene(model, theta_o, variant=variant))
    per = spp // passes
    values = np.array([float(np.mean(im)) for im in _render_passes(mi, scene, [per] * passes, seed=seed)])
    return FurnaceResult(theta_o_deg=theta_o, radiance=float(values.mean()), se=float(values.std(ddof=1) / math.sqrt(passes)),
                         spp=per * passes)
