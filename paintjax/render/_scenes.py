"""Mitsuba scene dicts: a paint sphere outdoors, a flat panel under a collimated beam, a white furnace.

Lengths are arbitrary scene units; angles in degrees. Every builder returns a dict for `mi.load_dict`
and needs Mitsuba (`require_mitsuba(variant)` is called); `environment_map` is NumPy only.

**Outdoor light** (`sphere_scene`, the previews of `render_paint`): y is up. The sky is an
equirectangular `envmap` generated here (`environment_map`): a blue-grey zenith of radiance
(0.22, 0.30, 0.45) brightening toward a near-white horizon of radiance 0.9, and a uniform grey ground
(radiance 0.15) below the horizon; the sky alone gives a horizontal surface an irradiance of 1.1 (red)
to 1.7 (blue). The sun is a `directional` emitter of irradiance 2.5 (white, on a plane facing it), 40°
above the horizon and 45° to the left of the camera as seen from the sphere, so the sphere shows its lit
face, its highlight and its flop toward the shadowed side.
"""

from __future__ import annotations

import math

import numpy as np

from ._bsdf import bsdf_dict, require_mitsuba

#: Sun elevation above the horizon [deg].
SUN_ELEVATION_DEG = 40.0
#: Sun azimuth from the camera direction (seen from the sphere), positive toward the camera's left [deg].
SUN_AZIMUTH_DEG = 45.0
#: Sun irradiance on a plane facing it (white, RGB).
SUN_IRRADIANCE = 2.5
#: Sky radiance at the zenith and at the horizon (linear RGB), and of the ground below the horizon.
SKY_ZENITH = (0.22, 0.30, 0.45)
SKY_HORIZON = (0.90, 0.90, 0.90)
GROUND = (0.15, 0.15, 0.15)
#: Camera of the sphere scene: distance from the centre of the unit sphere, height, field of view [deg].
CAMERA_DISTANCE, CAMERA_HEIGHT, CAMERA_FOV_DEG = 4.2, 0.8, 34.0
#: Half-size of the flat panel (scene units); detectors and the beam meet at its centre.
PANEL_HALF_SIZE = 5.0


def environment_map(width: int = 256, height: int = 128) -> np.ndarray:
    """The sky as an equirectangular linear-RGB image (Mitsuba's `envmap` layout: row 0 looks up, +y).

    Above the horizon the radiance runs from `SKY_HORIZON` at elevation 0 to `SKY_ZENITH` at 90° as
    sqrt(sin elevation); below it is the uniform `GROUND`. Azimuthally uniform (the sun is separate).

    Arguments:
        width, height: pixels (width = 2 height for square pixels), at least 8 × 4.

    Returns:
        float32 array (height, width, 3).
    """
    if not (isinstance(width, int) and isinstance(height, int) and width >= 8 and height >= 4):
        raise ValueError(f"width and height must be integers >= 8 and >= 4, got {width!r}, {height!r}")
    polar = math.pi * (np.arange(height) + 0.5) / height  # from +y
    elevation = 0.5 * math.pi - polar
    t = np.sqrt(np.clip(np.sin(elevation), 0.0, 1.0))[:, None]
    sky = np.asarray(SKY_HORIZON) * (1.0 - t) + np.asarray(SKY_ZENITH) * t
    rows = np.where((elevation > 0.0)[:, None], sky, np.asarray(GROUND))
    return np.ascontiguousarray(np.broadcast_to(rows[:, None, :], (height, width, 3)), dtype=np.float32)


def sun_direction() -> np.ndarray:
    """Unit vector from the scene toward the sun (y up, camera on +z)."""
    e, a = math.radians(SUN_ELEVATION_DEG), math.radians(SUN_AZIMUTH_DEG)
    return np.array([-math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a)])


def _rgb(value) -> dict:
    v = [float(value)] * 3 if np.ndim(value) == 0 else [float(x) for x in value]
    return {"type": "rgb", "value": v}


def _integrator(max_depth: int) -> dict:
    return {"type": "path", "max_depth": max_depth, "hide_emitters": False}


def sphere_scene(bsdf: dict, *, resolution: int = 512, variant: str | None = None) -> dict:
    """A unit sphere with `bsdf` under the sky and the sun (module docstring), seen by a perspective camera.

    Arguments:
        bsdf: a Mitsuba BSDF dict (`bsdf_dict(model)` for a paint).
        resolution: square image side in pixels.
        variant: Mitsuba variant (set here).

    Returns:
        The scene dict (path tracer, 4 bounces at most, the sky visible behind the sphere).
    """
    mi = require_mitsuba(variant)
    eye = [0.0, CAMERA_HEIGHT, CAMERA_DISTANCE]
    return {
        "type": "scene",
        "integrator": _integrator(4),
        "sensor": {
            "type": "perspective", "fov": CAMERA_FOV_DEG, "fov_axis": "x",
            "to_world": mi.ScalarTransform4f().look_at(origin=eye, target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0]),
            "sampler": {"type": "independent", "sample_count": 1},
            "film": {"type": "hdrfilm", "width": resolution, "height": resolution, "pixel_format": "rgb",
                     "rfilter": {"type": "gaussian"}},
        },
        "sky": {"type": "envmap", "bitmap": mi.Bitmap(environment_map())},
        "sun": {"type": "directional", "direction": (-sun_direction()).tolist(), "irradiance": _rgb(SUN_IRRADIANCE)},
        "paint": {"type": "sphere", "center": [0.0, 0.0, 0.0], "radius": 1.0, "bsdf": bsdf},
    }


def paint_sphere_scene(model, *, resolution: int = 512, variant: str | None = None) -> dict:
    """`sphere_scene` with the paint `model` (a `CarPaintBRDF` or its JSON dict)."""
    require_mitsuba(variant)
    return sphere_scene(bsdf_dict(model), resolution=resolution, variant=variant)


def _radiancemeter(toward: np.ndarray) -> dict:
    """A 1-pixel sensor at distance 3 from the panel centre looking at it along −`toward`."""
    toward = np.asarray(toward, dtype=float) / np.linalg.norm(toward)
    return {"type": "radiancemeter", "origin": (3.0 * toward).tolist(), "direction": (-toward).tolist(),
            "sampler": {"type": "independent", "sample_count": 1},
            "film": {"type": "hdrfilm", "width": 1, "height": 1, "pixel_format": "rgb", "rfilter": {"type": "box"}}}


def _in_plane(polar_deg: float) -> np.ndarray:
    """Unit vector in the x–z plane at signed polar angle (positive toward +x, z = panel normal)."""
    t = math.radians(polar_deg)
    return np.array([math.sin(t), 0.0, math.cos(t)])


def panel_scene(model, detector_polar_deg, *, illumination_deg: float = 45.0, irradiance: float = 1.0,
                variant: str | None = None) -> dict:
    """A flat paint panel (z = normal) under a collimated beam, with one radiance meter per detector.

    The `directional` emitter comes from the −x side at `illumination_deg` from the normal, with
    `irradiance` on a plane facing the beam (so E cos θi on the panel); there is no other light. The
    detectors lie in the x–z plane at the signed polar angles given (positive: the specular, +x side),
    each a `radiancemeter` looking at the panel centre; sensor k of the scene is detector k.

    Arguments:
        model: a `CarPaintBRDF` (or its JSON dict).
        detector_polar_deg: signed detector polar angles [deg], within ±85.
        illumination_deg: illumination polar angle [deg].
        irradiance: beam irradiance E (on a plane facing it).
        variant: Mitsuba variant (set here).

    Returns:
        The scene dict (direct lighting: path tracer with 2 vertices at most).
    """
    require_mitsuba(variant)
    scene = {"type": "scene", "integrator": _integrator(2),
             "panel": {"type": "rectangle", "to_world": _scale(PANEL_HALF_SIZE, variant), "bsdf": bsdf_dict(model)},
             "beam": {"type": "directional", "direction": (-_in_plane(-illumination_deg)).tolist(), "irradiance": _rgb(irradiance)}}
    for k, polar in enumerate(np.atleast_1d(np.asarray(detector_polar_deg, dtype=float))):
        scene[f"detector_{k}"] = _radiancemeter(_in_plane(float(polar)))
    return scene


def furnace_scene(model, theta_o_deg: float, *, variant: str | None = None) -> dict:
    """The flat panel inside a uniform environment of radiance 1 (a `constant` emitter), one radiance meter.

    The meter sits at polar angle `theta_o_deg` (azimuth 0) and reads the panel's directional albedo
    ∫ f cosθ dω + R_coat(θo), the coat's delta reflection included (found by BSDF sampling only).

    Returns:
        The scene dict (path tracer with 2 vertices at most: one bounce, emitter and BSDF sampling with MIS).
    """
    require_mitsuba(variant)
    return {"type": "scene", "integrator": _integrator(2),
            "panel": {"type": "rectangle", "to_world": _scale(PANEL_HALF_SIZE, variant), "bsdf": bsdf_dict(model)},
            "environment": {"type": "constant", "radiance": _rgb(1.0)},
            "detector": _radiancemeter(_in_plane(float(theta_o_deg)))}


def _scale(s: float, variant: str):
    mi = require_mitsuba(variant)
    return mi.ScalarTransform4f().scale([s, s, 1.0])
