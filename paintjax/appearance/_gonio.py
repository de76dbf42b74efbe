"""The gonio BRDF of a simulated paint: the tracer's reflectance factor over incidences and outgoing
directions in and out of the plane of incidence, with statistical errors, and the MA98 geometries.

Each incidence is one tracer run whose detectors are the grid's outgoing directions (plus, at 45°
and 15°, the MA98 geometries), forward tracing with next-event estimation to every detector (the
bidirectional pass costs a reverse pass per detector, so it is off here). Directions follow the
instrument convention (`paintjax.instrument._geometry`): the source at azimuth 180° (the −x side),
the specular direction at azimuth 0°, the paint statistically isotropic, so outgoing azimuths
0°–180° cover the hemisphere.
"""

from __future__ import annotations

import dataclasses
import sys
import time

import numpy as np

from ..instrument._geometry import custom_geometry, direction

#: Meaning of a cached gonio table (bump to re-trace).
GONIO_VERSION = 1
#: Default illumination polar angles [deg] (0–80°; 15° and 45° carry the MA98 detectors).
DEFAULT_INCIDENCES = (0.0, 15.0, 30.0, 45.0, 60.0, 80.0)
#: Default outgoing polar angles and azimuths (relative to the specular side) [deg].
DEFAULT_POLAR = (0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0)
DEFAULT_AZIMUTH = (0.0, 45.0, 90.0, 135.0, 180.0)
#: Default rays per incidence.
DEFAULT_RAYS = 100_000

# The MA98's out-of-plane detectors are fixed in the instrument, the same for both illuminations:
# unit vectors (x toward the specular side, z the normal), as its geometry names state them.
_OUT_OF_PLANE = {"A": (0.640856, 0.422618, 0.640856), "B": (0.0, 0.707107, 0.707107)}


def _polar_azimuth(v) -> tuple[float, float]:
    v = np.asarray(v, dtype=float) / np.linalg.norm(v)
    return float(np.degrees(np.arccos(v[2]))), float(np.degrees(np.arctan2(v[1], v[0])))


def _aspecular(illumination_deg: float, polar_deg: float, azimuth_deg: float) -> float:
    """Angle between a detector and the specular direction [deg], unsigned (the size of an MA98 name's aspecular angle)."""
    spec = np.asarray(direction(illumination_deg, 0.0))
    d = np.asarray(direction(polar_deg, azimuth_deg))
    return float(np.degrees(np.arccos(np.clip(spec @ d, -1.0, 1.0))))


def ma98_geometries() -> list[dict]:
    """The 19 MA98 geometries: name, illumination polar angle, detector polar and azimuth [deg].

    In-plane: 45° illumination at aspecular −15, 15, 25, 45, 75, 110; 15° illumination at −45, −15,
    15, 45, 80. Out of plane: the detectors (0.641, ±0.423, 0.641) and (0, ±0.707, 0.707), named by
    their aspecular angle and azimuth for each illumination (45as25az±90, 45as60az±125.3,
    15as38.3az±43, 15as46.9az±104.5).
    """
    rows = []
    for theta_i, gammas in ((45.0, (-15, 15, 25, 45, 75, 110)), (15.0, (-45, -15, 15, 45, 80))):
        for g in gammas:
            signed = theta_i - g
            rows.append({"name": f"{theta_i:g}as{g:g}", "illumination_deg": theta_i, "polar_deg": abs(signed),
                         "azimuth_deg": 0.0 if signed >= 0 else 180.0})
    names = {45.0: {"A": "45as25az{s}90", "B": "45as60az{s}125.3"}, 15.0: {"A": "15as38.3az{s}43", "B": "15as46.9az{s}104.5"}}
    for theta_i in (45.0, 15.0):
        for key, (x, y, z) in _OUT_OF_PLANE.items():
            for sign in (1.0, -1.0):
                polar, az = _polar_azimuth((x, sign * y, z))
                rows.append({"name": names[theta_i][key].format(s="" if sign > 0 else "-"), "illumination_deg": theta_i,
                             "polar_deg": polar, "azimuth_deg": az})
    return rows


_COLUMNS = ("illumination_deg", "polar_deg", "azimuth_deg", "reflectance_factor", "reflectance_factor_se", "name")


@dataclasses.dataclass(frozen=True)
class GonioTable:
    """Reflectance factors R = π f of a paint at k (incidence, outgoing) pairs, with batch-means SEs.

    `wi`, `wo` are unit vectors (k, 3) in air; `name` is the MA98 geometry's name or "" for grid points;
    `paint` the paint's description (sample and overrides), `rays` per incidence.
    """

    illumination_deg: np.ndarray  # (k,)
    polar_deg: np.ndarray  # (k,) outgoing polar angle
    azimuth_deg: np.ndarray  # (k,) outgoing azimuth (0: specular side)
    reflectance_factor: np.ndarray  # (k,)
    reflectance_factor_se: np.ndarray  # (k,)
    name: np.ndarray  # (k,) str
    paint: dict
    rays: int
    seconds: float

    @property
    def wi(self) -> np.ndarray:
        return np.asarray(direction(self.illumination_deg, np.full_like(self.illumination_deg, 180.0)))

    @property
    def wo(self) -> np.ndarray:
        return np.asarray(direction(self.polar_deg, self.azimuth_deg))

    @property
    def is_ma98(self) -> np.ndarray:
        return self.name != ""

    def select(self, mask) -> GonioTable:
        """The entries where `mask` (k,) is True (e.g. `table.is_ma98`)."""
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != self.name.shape or not mask.any():
            raise ValueError(f"mask must be {self.name.size} booleans with at least one True")
        return dataclasses.replace(self, **{f: getattr(self, f)[mask] for f in _COLUMNS})

    def save_csv(self, path):
        """One row per entry (angles, R, its SE, L*, its SE, MA98 name), written atomically."""
        from .._io import atomic_write_bytes

        L, se = self.lightness()
        lines = ["illumination_deg,polar_deg,azimuth_deg,reflectance_factor,reflectance_factor_se,L_star,L_star_se,ma98"]
        for row in zip(self.illumination_deg, self.polar_deg, self.azimuth_deg, self.reflectance_factor, self.reflectance_factor_se, L, se, self.name):
            lines.append(",".join(f"{v:.6g}" for v in row[:7]) + f",{row[7]}")
        return atomic_write_bytes(path, ("\n".join(lines) + "\n").encode())

    def lightness(self) -> tuple[np.ndarray, np.ndarray]:
        """L* and its (delta-method) standard error per entry."""
        from ..tracer._trace import lightness_with_se

        L, se = lightness_with_se(self.reflectance_factor, self.reflectance_factor_se)
        return np.asarray(L), np.asarray(se)


def _check_angles(name: str, values, lo: float, hi: float) -> np.ndarray:
    try:
        v = np.atleast_1d(np.asarray(values, dtype=float))
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be angles in [{lo:g}, {hi:g}] degrees, got {values!r}") from None
    if v.ndim != 1 or v.size == 0 or np.any(~np.isfinite(v)) or np.any((v < lo) | (v > hi)) or np.unique(v).size != v.size:
        raise ValueError(f"{name} must be distinct angles in [{lo:g}, {hi:g}] degrees, got {values!r}")
    return v


def _detectors(theta_i: float, polar, azimuth) -> list[tuple[float, float, str]]:
    """Grid directions at one incidence (the normal once), then this incidence's MA98 detectors."""
    dets = [(0.0, 0.0, "")] if 0.0 in polar else []
    dets += [(float(p), float(a), "") for p in polar if p > 0 for a in azimuth]
    dets += [(g["polar_deg"], g["azimuth_deg"], g["name"]) for g in ma98_geometries() if g["illumination_deg"] == theta_i]
    return dets


def gonio_table(
    sample: str = "silver1",
    *,
    incidences_deg=DEFAULT_INCIDENCES,
    polar_deg=DEFAULT_POLAR,
    azimuth_deg=DEFAULT_AZIMUTH,
    rays: int = DEFAULT_RAYS,
    seed: int = 0,
    brdf: str = "wave",
    options=None,
    progress: bool = False,
    use_cache: bool = True,
    **paint,
) -> GonioTable:
    """Tabulate a simulated paint's BRDF with the tracer (cached on disk by content).

    Arguments:
        sample: reference sample the paint starts from ("silver1", "silver2").
        incidences_deg: illumination polar angles in [0, 80]; 45° and 15° add the MA98 detectors.
        polar_deg: outgoing polar angles in [0, 80]; azimuth_deg: outgoing azimuths in [0, 180]
            (0: the specular side), one detector per (polar > 0, azimuth) pair plus the normal.
        rays: rays per incidence; seed: the tracer's seed (each incidence offsets it).
        brdf: platelet BRDF ("wave", "kirchhoff").
        options: `TracerOptions` (default: forward tracing, `reverse_share=0`; e.g. more `lanes` on a GPU).
        progress: a line per incidence on stderr (its L* SE range and seconds, the time left).
        use_cache: False re-traces without reading or writing the cache.
        **paint: overrides passed to `paintjax.simulate` (shape, scale, sigma, tau, pvc, thickness,
            d50, platelet_thickness, primer_albedo, waviness).

    Returns:
        A `GonioTable`.
    """
    from .._cache import cached_arrays
    from .._pipeline import simulate
    from ..brdf._table import TABLE_VERSION
    from ..inverse._tracer_forward import TRACER_FORWARD_VERSION  # the tracer physics' version (emulators use it too)
    from ..tracer._options import TracerOptions
    from ..tracer._trace import _seed_state, check_ray_count

    incidences = _check_angles("incidences_deg", incidences_deg, 0.0, 80.0)
    polar = _check_angles("polar_deg", polar_deg, 0.0, 80.0)
    azimuth = _check_angles("azimuth_deg", azimuth_deg, 0.0, 180.0)
    given = options is not None
    if given and not isinstance(options, TracerOptions):
        raise ValueError(f"options must be a TracerOptions, got {type(options).__name__}")
    options = options if given else TracerOptions(reverse_share=0.0)
    check_ray_count(rays, options)
    _seed_state(seed)
    allowed = {"shape", "scale", "sigma", "tau", "pvc", "thickness", "d50", "platelet_thickness", "primer_albedo", "waviness"}
    unknown = sorted(set(paint) - allowed)
    if unknown:
        raise ValueError(f"unknown paint parameter(s) {unknown}; allowed: {sorted(allowed)}")
    paint = {k: (None if v is None else float(v)) for k, v in paint.items()}
    description = {"sample": sample, "brdf": brdf, **{k: v for k, v in paint.items() if v is not None}}
    inputs = {"version": GONIO_VERSION, "table_version": TABLE_VERSION, "tracer_version": TRACER_FORWARD_VERSION, "paint": description, "incidences": incidences,
              "polar": polar, "azimuth": azimuth, "rays": int(rays), "seed": int(seed)}
    if given:  # the default's key stays that of the shipped tables
        inputs["options"] = repr(options)
    def build():
        cols = {k: [] for k in _COLUMNS}
        t0 = time.perf_counter()
        for j, theta_i in enumerate(incidences):
            dets = _detectors(float(theta_i), polar, azimuth)
            geometry = custom_geometry(float(theta_i), [d[0] for d in dets], [d[1] for d in dets])
            out = simulate(sample, brdf=brdf, geometry=geometry, rays=int(rays), seed=int(seed) + 7919 * j, options=options, **paint)
            cols["illumination_deg"] += [float(theta_i)] * len(dets)
            cols["polar_deg"] += [d[0] for d in dets]
            cols["azimuth_deg"] += [d[1] for d in dets]
            cols["name"] += [d[2] for d in dets]
            cols["reflectance_factor"] += list(np.asarray(out["reflectance_factor"], dtype=float))
            cols["reflectance_factor_se"] += list(np.asarray(out["reflectance_factor_se"], dtype=float))
            if progress:
                spent = time.perf_counter() - t0
                se = np.asarray(out["L_star_se"], dtype=float)
                print(f"  gonio {sample}: incidence {theta_i:g}° ({j + 1}/{incidences.size}), {len(dets)} directions, "
                      f"L* SE {se.min():.2f}–{se.max():.2f}, {spent:.0f} s, about {spent / (j + 1) * (incidences.size - j - 1):.0f} s left",
                      file=sys.stderr, flush=True)
        return {k: np.asarray(v) for k, v in cols.items()} | {"seconds": np.asarray(time.perf_counter() - t0)}

    d, _ = cached_arrays("gonio", inputs, build, use_cache=use_cache)
    return GonioTable(
        illumination_deg=np.asarray(d["illumination_deg"], dtype=float), polar_deg=np.asarray(d["polar_deg"], dtype=float),
        azimuth_deg=np.asarray(d["azimuth_deg"], dtype=float), reflectance_factor=np.asarray(d["reflectance_factor"], dtype=float),
        reflectance_factor_se=np.asarray(d["reflectance_factor_se"], dtype=float), name=np.asarray(d["name"]).astype(str),
        paint=description, rays=int(rays), seconds=float(d["seconds"]))


