"""Peer benchmark: paintjax's ray tracer against Mitsuba 3's `path` integrator on the same paint scene (issue 26).

Scene (µm): the Silver #1 platelet array, seed 0 (aluminium boxes centre ± w/2 u ± w/2 v ± t/2 n,
periodic tile), a 20 µm basecoat of binder n = 1.5 under a 50 µm clearcoat of the same index (so the
only interface is the coat top), a Lambertian primer of albedo 0.3 at z = 0, light at 45°, the five
MA98 directions. Both tracers run in this process, strictly alternating over `--rounds`, warm (one
warm-up each first); reported: medians and min–max of paths/s, paths per CPU-second (process CPU
time, all threads), segments/s, their ratios paintjax / Mitsuba, the machine and the load.

paintjax: `trace` (wavefront, forward only: `reverse_share=0`), `--rays` paths per round; mirror
platelets (`MirrorBRDF`) with 2° detector cones, or the wave BRDF with point detectors.

Mitsuba (`path`, max_depth 10, Russian roulette from depth 5, its defaults otherwise):
* the boxes as one PLY mesh (12 triangles each, face normals) for the tile and its 8 periodic images
  (3 × 3 tiles), so platelets straddling the tile edges are whole and paths that wander sideways keep
  seeing platelets for a tile's width; the sensors see the central tile only. Beyond the block the
  primer and the coat go on (20 tiles wide) without platelets; the fraction of vertices there is reported;
* `conductor` (mirror) or `roughconductor` (wave: Beckmann α = 2σ/τ, the Kirchhoff limit of the wave
  BRDF, without its coherent part) with aluminium's index divided by the binder's (paintjax's
  Fresnel in the binder); `diffuse` 0.3 primer; a `dielectric` (1.5 / air) rectangle at the coat top;
* the light: not `directional`. Mitsuba's shadow rays stop at a dielectric, so a delta emitter under
  a coat is never reached (the image is black). It is a distant disc `area` emitter at 45° subtending
  a 2° half-angle cone, hit by BSDF-sampled paths through the coat; by reciprocity this matches
  paintjax's collimated beam and 2° detector cones (mirror; with the wave BRDF paintjax's detectors
  are points and Mitsuba's source stays a 2° disc);
* the sensors: five `orthographic` cameras, one per MA98 direction (a `batch` sensor, one render per
  round), each framing the central tile; paths = 5 × resolution² × spp per round.

Segments (per unit of work). paintjax: counted by `plain_trace_counts` on the plain
`vmap(while_loop)` tracer, which runs the same path physics and random numbers as `trace` (the
counted paths are `trace`'s: the reflectance factors of both are reported and agree); a segment is a
straight piece ending at a platelet, the primer or the coat surface (the coat transit is closed
form). Mitsuba: a Python/Dr.Jit replica of `path`'s loop (same scene, BSDFs, depth limit and
roulette rule) counts its ray casts (`ray_intersect`) and shadow rays (emitter samples with a non-zero
pdf); its image means are reported next to `mi.render`'s as a check. Mitsuba's cast count includes
the camera ray to the coat and the escape ray above it, which paintjax does in closed form:
"interior" segments leave them out.

Reflectance factors (R = πL/E per detector) come with the timings as a check that the scenes match:
Mitsuba's per camera is its image mean / (cos 45° sin² 2°). They differ by more than noise, for known
reasons: paintjax turns the instrument by a random azimuth per path (an average over tile
orientations) where Mitsuba sees one (`--fixed-azimuth` turns that off: mirror, 2026-12-04, 262 144
paths against 128² × 64 per camera: R = 9.55 ± 0.20, 0.68, 0.036, 0.053, 0.058 against Mitsuba's 10.6,
0.63, 0.034, 0.053, 0.035); the cone averages over exit (paintjax) or incident (Mitsuba) directions;
Mitsuba's block is 3 × 3 tiles, paintjax's tile periodic; the wave BRDF's coherent lobe has no
counterpart in `roughconductor`.

LLVM: Mitsuba's `llvm_*` variants need Dr.Jit's LLVM backend with LLVM 17 or newer (Debian:
`apt-get install libllvm19`, or set `DRJIT_LIBLLVM_PATH` to a libLLVM.so). Without it
`paintjax.render.default_variant()` falls back to `scalar_rgb` (and the replica then counts fewer paths
one by one); `$PAINTJAX_MITSUBA_VARIANT` overrides the choice.

Usage: python benchmarks/peer_mitsuba.py [--rounds 5] [--rays 65536] [--spp 64] [--resolution 64] [--brdf mirror|wave]
       [--count-rays 4096] [--count-paths 65536] [--fixed-azimuth]
Output: one JSON line on stdout; benchmarks/output/peer_mitsuba.json (runs by BRDF, written atomically).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
import warnings
from datetime import date
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from paintjax import MirrorBRDF, atomic_write_json, build_grid, load_sample, ma98_geometry, platelet_brdf, sample_array  # noqa: E402
from paintjax.optics import aluminium_index  # noqa: E402
from paintjax.render import default_variant, require_mitsuba  # noqa: E402
from paintjax.tracer import TracerOptions, build_scene, plain_trace_counts, trace  # noqa: E402

OUT = Path(__file__).resolve().parent / "output" / "peer_mitsuba.json"
PRIMER_ALBEDO = 0.3
CONE_DEG = 2.0  # paintjax's detector cones (mirror) and Mitsuba's emitter cone
MAX_DEPTH, RR_DEPTH = 10, 5  # Mitsuba `path`: the brief's depth, its default roulette depth
EMITTER_DISTANCE_UM, CAMERA_DISTANCE_UM = 1.0e6, 1.0e4
IMAGES = 1  # periodic images on each side of the tile in the mesh (3 × 3 tiles)
SLAB_TILES = 20.0  # primer and coat rectangles, in tiles
WAVE_WAVELENGTH_UM = 0.5  # the wave BRDF's default wavelength (`platelet_brdf`)

# Unit cube corners (bit 0: +u, bit 1: +v, bit 2: +n) and its 12 outward (counter-clockwise) triangles
_CORNERS = np.array([[(i & 1) * 2 - 1, ((i >> 1) & 1) * 2 - 1, ((i >> 2) & 1) * 2 - 1] for i in range(8)], dtype=float)
_TRIANGLES = np.array([[0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4],
                       [2, 6, 7], [2, 7, 3], [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5]])


def say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def box_mesh(array, images: int = IMAGES):
    """Vertices (V, 3) and triangles (F, 3) of every platelet box and its periodic images within ± `images` tiles."""
    c = np.asarray(array.centers, dtype=float)
    n = np.asarray(array.normals, dtype=float)
    u = np.asarray(array.axes_u, dtype=float)
    v = np.cross(n, u)
    half = np.stack([np.asarray(array.widths, dtype=float) / 2] * 2 + [np.full(len(c), array.thickness / 2)], axis=1)
    axes = np.stack([u, v, n], axis=1) * half[:, :, None]  # (N, 3 axes, 3)
    corners = c[:, None, :] + np.einsum("ka,nab->nkb", _CORNERS, axes)  # (N, 8, 3)
    Lx, Ly = (float(t) for t in array.tile)
    shifts = np.array([[i * Lx, j * Ly, 0.0] for i in range(-images, images + 1) for j in range(-images, images + 1)])
    verts = (corners[None] + shifts[:, None, None, :]).reshape(-1, 3)
    boxes = len(shifts) * len(c)
    faces = (np.arange(boxes)[:, None, None] * 8 + _TRIANGLES[None]).reshape(-1, 3)
    tri = verts[faces]  # outward check: every face normal points away from its box's centre
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    centre = np.repeat((c[None] + shifts[:, None, :]).reshape(-1, 3), 12, axis=0)
    assert np.all(np.sum(normal * (tri.mean(axis=1) - centre), axis=1) > 0), "box triangles must wind outward"
    return verts, faces


def write_ply(path: Path, verts: np.ndarray, faces: np.ndarray) -> None:
    """Binary little-endian PLY: float32 vertices, triangles as uchar-counted int32 lists."""
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(verts)}\nproperty float x\nproperty float y\n"
              f"property float z\nelement face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n")
    f = np.zeros(len(faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    f["n"], f["i"] = 3, faces
    with open(path, "wb") as fh:
        fh.write(header.encode())
        fh.write(np.ascontiguousarray(verts, dtype="<f4").tobytes())
        fh.write(f.tobytes())


def _look_at(mi, origin, target, up, scale=(1.0, 1.0, 1.0)):
    T = mi.ScalarTransform4f
    return T().look_at(origin=[float(x) for x in origin], target=[float(x) for x in target], up=list(up)) @ T().scale(list(scale))


def mitsuba_scene(mi, ply: Path, array, geometry, kind: str, h_c: float, n: float, resolution: int, spp: int):
    """The paint panel in Mitsuba: platelet mesh, primer, coat top, disc emitter at the source, one orthographic camera per detector."""
    Lx, Ly = (float(t) for t in array.tile)
    top = float(array.basecoat_thickness) + h_c
    centre = np.array([Lx / 2, Ly / 2, top])
    metal = complex(MirrorBRDF(n_binder=n).metal_index) if kind == "mirror" else complex(np.asarray(aluminium_index(WAVE_WAVELENGTH_UM)))
    if kind == "mirror":
        metal_bsdf = {"type": "conductor", "eta": metal.real / n, "k": metal.imag / n}
    else:
        s = load_sample("silver1")
        metal_bsdf = {"type": "roughconductor", "distribution": "beckmann", "alpha": 2.0 * s.sigma.value / s.tau.value,
                      "eta": metal.real / n, "k": metal.imag / n}
    T = mi.ScalarTransform4f
    slab = [SLAB_TILES * Lx / 2, SLAB_TILES * Ly / 2, 1.0]
    src = np.asarray(geometry.illumination_air(), dtype=float)
    r_disc = EMITTER_DISTANCE_UM * np.tan(np.deg2rad(CONE_DEG))
    sensors = {}
    for j, w in enumerate(np.asarray(geometry.detectors_air(), dtype=float)):
        sensors[f"detector{j}"] = {"type": "orthographic", "near_clip": 1.0, "far_clip": 10 * CAMERA_DISTANCE_UM,
                                   "to_world": _look_at(mi, centre + CAMERA_DISTANCE_UM * w, centre, (0, 1, 0), (w[2] * Lx / 2, Ly / 2, 1))}
    m = len(sensors)
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": MAX_DEPTH, "rr_depth": RR_DEPTH},
        "sensor": {"type": "batch", **sensors, "film": {"type": "hdrfilm", "width": m * resolution, "height": resolution,
                                                        "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                   "sampler": {"type": "independent", "sample_count": spp}},
        "platelets": {"type": "ply", "filename": str(ply), "face_normals": True, "bsdf": metal_bsdf},
        "primer": {"type": "rectangle", "to_world": T().translate([Lx / 2, Ly / 2, 0.0]) @ T().scale(slab),
                   "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": PRIMER_ALBEDO}}},
        "coat": {"type": "rectangle", "to_world": T().translate([Lx / 2, Ly / 2, top]) @ T().scale(slab),
                 "bsdf": {"type": "dielectric", "int_ior": n, "ext_ior": 1.0}},
        "source": {"type": "disk", "to_world": _look_at(mi, centre + EMITTER_DISTANCE_UM * src, centre, (0, 1, 0), (r_disc, r_disc, 1)),
                   "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 1.0}}},
    })


def _power(a, b, dr):
    w = a * a / dr.maximum(a * a + b * b, 1e-30)  # path.cpp's power heuristic; 0 where it is 0/0 or not finite
    return dr.select(dr.isfinite(w), w, 0.0)


def mitsuba_walk(mi, dr, scene, paths: int, seed: int, tile):
    """Replica of `path`'s loop (Mitsuba 3.x path.cpp) that counts its work; returns (counts, radiance per sensor).

    Counts: casts (every `ray_intersect`), camera (the first casts), escapes (casts that hit nothing or
    the emitter), platelet / primer / coat hits, shadow rays (emitter samples with pdf > 0: the
    `ray_test` that `sample_emitter_direction` makes for them), outside (hits beyond the replicated block).
    Scalar variants: one path per call (`paths` = 1), Python conditions instead of masks around
    calls through pointers that may be null, as path.cpp's early exit does.
    """
    jit = dr.is_jit_v(mi.Float)
    sensor = scene.sensors()[0]
    sampler = sensor.sampler().clone()
    sampler.seed(seed, paths)
    ctx = mi.BSDFContext()
    film_pos = sampler.next_2d()
    ray, _ = sensor.sample_ray(0.0, sampler.next_1d(), film_pos, mi.Point2f(0.5))
    throughput, result, eta = mi.Spectrum(1.0), mi.Spectrum(0.0), mi.Float(1.0)
    depth, active = dr.zeros(mi.UInt32, paths), dr.full(mi.Bool, True, paths)
    prev_si, prev_pdf, prev_delta = dr.zeros(mi.Interaction3f), mi.Float(1.0), mi.Bool(True)
    keys = ("casts", "camera", "escapes", "platelet_hits", "primer_hits", "coat_hits", "shadow_rays", "outside")
    count = dict.fromkeys(keys, 0)
    Lx, Ly = tile
    first = True
    while True:
        n_active = _n(dr, active)
        if n_active == 0:
            break
        count["casts"] += n_active
        count["camera"] += n_active if first else 0
        si = scene.ray_intersect(ray, mi.RayFlags.All, first, active)
        first = False
        emitter = si.emitter(scene, active)
        hit_em = active & (emitter != None)  # noqa: E711 (a Dr.Jit pointer array)
        if jit or hit_em:
            ds = mi.DirectionSample3f(scene, si, prev_si)
            em_pdf = scene.pdf_emitter_direction(prev_si, ds, hit_em & _not(dr, prev_delta)) if jit or not prev_delta else 0.0
            mis = _power(prev_pdf, dr.select(prev_delta, 0.0, em_pdf), dr)
            result += dr.select(hit_em, throughput * ds.emitter.eval(si, hit_em & (prev_pdf > 0)) * mis, 0.0)
        valid = si.is_valid()
        count["escapes"] += _n(dr, active & (_not(dr, valid) | hit_em))
        beyond = (dr.abs(si.p.x - Lx / 2) > (IMAGES + 0.5) * Lx) | (dr.abs(si.p.y - Ly / 2) > (IMAGES + 0.5) * Ly)
        count["outside"] += _n(dr, active & valid & beyond)
        active_next = active & (depth + 1 < MAX_DEPTH) & valid
        if not (jit or active_next):
            active = active_next
            continue
        bsdf = si.bsdf(ray)
        flags = bsdf.flags()
        coat = mi.has_flag(flags, mi.BSDFFlags.Transmission)
        primer = mi.has_flag(flags, mi.BSDFFlags.DiffuseReflection)
        hit_sh = active & valid & _not(dr, hit_em)
        count["coat_hits"] += _n(dr, hit_sh & coat)
        count["primer_hits"] += _n(dr, hit_sh & primer)
        count["platelet_hits"] += _n(dr, hit_sh & _not(dr, coat | primer))
        active_em = active_next & mi.has_flag(flags, mi.BSDFFlags.Smooth)
        ds_e, em_w = scene.sample_emitter_direction(si, sampler.next_2d(), False, active_em)
        active_em &= ds_e.pdf != 0.0  # Mitsuba's `ray_test` of test_visibility, traced here to count it
        count["shadow_rays"] += _n(dr, active_em)
        active_em &= _not(dr, scene.ray_test(si.spawn_ray_to(ds_e.p), active_em))
        wo = si.to_local(ds_e.d)
        bs, bsdf_w = bsdf.sample(ctx, si, sampler.next_1d(), sampler.next_2d(), active_next)
        f_em, pdf_em = bsdf.eval_pdf(ctx, si, wo, active_em)
        result += dr.select(active_em, throughput * f_em * em_w * dr.select(ds_e.delta, 1.0, _power(ds_e.pdf, pdf_em, dr)), 0.0)
        ray = dr.select(active_next, si.spawn_ray(si.to_world(bs.wo)), ray)
        throughput = dr.select(active_next, throughput * bsdf_w, throughput)
        eta = dr.select(active_next, eta * bs.eta, eta)
        prev_si = dr.select(active_next, mi.Interaction3f(si), prev_si)
        prev_pdf = dr.select(active_next, bs.pdf, prev_pdf)
        prev_delta = dr.select(active_next, mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta), prev_delta)
        depth = dr.select(active & valid, depth + 1, depth)
        t_max = dr.max(throughput)
        q = dr.minimum(t_max * eta * eta, 0.95)
        rr = depth >= RR_DEPTH
        go = sampler.next_1d() < q
        throughput = dr.select(active_next & rr, throughput * dr.rcp(dr.maximum(q, 1e-30)), throughput)
        active = active_next & (_not(dr, rr) | go) & (t_max != 0.0)
        sampler.schedule_state()
        dr.eval(ray, throughput, result, eta, depth, active, prev_si, prev_pdf, prev_delta)
    value = np.asarray(result.x if hasattr(result, "x") else result[0], dtype=float).reshape(-1)
    x = np.asarray(film_pos.x, dtype=float).reshape(-1)
    return count, value, x


def _not(dr, mask):
    """Logical not of a Dr.Jit mask or, in scalar variants, a bool (where `~` would give an int)."""
    return dr.select(mask, False, True)


def _n(dr, mask) -> int:
    c = dr.count(mask)
    return int(c[0]) if dr.is_array_v(c) else int(c)


def spread(xs) -> dict:
    xs = np.asarray(xs, dtype=float)
    return {"median": float(np.median(xs)), "min": float(xs.min()), "max": float(xs.max())}


def machine() -> dict:
    model = ""
    try:
        model = next(line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return {"platform": platform.platform(), "cpu": model or platform.processor(), "cores": os.cpu_count(),
            "python": platform.python_version(),
            "jax": jax.__version__, "jax_backend": jax.default_backend()}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5, help="interleaved rounds (paintjax, Mitsuba, paintjax, ...)")
    ap.add_argument("--rays", type=int, default=65536, help="paintjax paths per round")
    ap.add_argument("--spp", type=int, default=64, help="Mitsuba samples per pixel")
    ap.add_argument("--resolution", type=int, default=64, help="Mitsuba pixels per side of each of the five cameras")
    ap.add_argument("--brdf", choices=("mirror", "wave"), default="mirror")
    ap.add_argument("--count-rays", type=int, default=4096, help="paintjax paths counted on the plain tracer")
    ap.add_argument("--count-paths", type=int, default=65536, help="Mitsuba paths counted by the replica of `path`")
    ap.add_argument("--fixed-azimuth", action="store_true",
                    help="paintjax without its random instrument azimuth per path: the tile orientation Mitsuba sees (a scene check)")
    args = ap.parse_args()
    warnings.filterwarnings("ignore", message="light reached these detectors")  # short runs: far angles unresolved, throughput unaffected
    t_start = time.perf_counter()
    load_before = os.getloadavg()

    # --- the scene, paintjax side
    s = load_sample("silver1")
    n, h_c = float(s.binder_index), float(s.clearcoat_thickness)
    array = sample_array("silver1", seed=0)
    grid = build_grid(array)
    if args.brdf == "mirror":
        brdf, geo = MirrorBRDF(n_binder=n), ma98_geometry(45.0, detector_aperture_deg=CONE_DEG)
    else:
        brdf, geo = platelet_brdf("wave", sigma=s.sigma.value, tau=s.tau.value, n=n), ma98_geometry(45.0)
    opt = TracerOptions(reverse_share=0.0, randomize_azimuth=not args.fixed_azimuth)
    kw = dict(grid=grid, n=n, clearcoat_thickness=h_c, primer_albedo=PRIMER_ALBEDO, options=opt)
    m = geo.num_detectors
    c = np.asarray(array.centers, dtype=float)
    say(f"array: {len(c)} platelets, tile {array.tile} µm, load {load_before[0]:.2f}")

    # --- the scene, Mitsuba side
    variant = default_variant()
    mi = require_mitsuba(variant)
    import drjit as dr

    tmp = tempfile.TemporaryDirectory(prefix="peer_mitsuba_")
    ply = Path(tmp.name) / "platelets.ply"
    verts, faces = box_mesh(array)
    write_ply(ply, verts, faces)
    t0 = time.perf_counter()
    scene = mitsuba_scene(mi, ply, array, geo, args.brdf, h_c, n, args.resolution, args.spp)
    t_load = time.perf_counter() - t0
    say(f"mitsuba {mi.__version__} {variant}: {len(faces)} triangles, scene load {t_load:.1f} s")

    # --- warm-up (compilation) of both
    t0 = time.perf_counter()
    trace(array, geo, brdf, rays=8 * opt.lanes, seed=99, **kw)
    t_pj_warm = time.perf_counter() - t0
    t0 = time.perf_counter()
    np.asarray(mi.render(scene, seed=99))
    t_mi_warm = time.perf_counter() - t0
    say(f"warm-up: paintjax {t_pj_warm:.1f} s, mitsuba {t_mi_warm:.1f} s")

    # --- interleaved rounds
    paths_mi = m * args.resolution**2 * args.spp
    rows, loads, R_pj, R_mi = {"pj_wall": [], "pj_trace": [], "pj_cpu": [], "mi_wall": [], "mi_cpu": []}, [], [], []
    for r in range(args.rounds):
        loads.append(os.getloadavg()[0])
        c0, w0 = time.process_time(), time.perf_counter()
        res = trace(array, geo, brdf, rays=args.rays, seed=1000 + r, **kw)
        rows["pj_wall"].append(time.perf_counter() - w0)
        rows["pj_cpu"].append(time.process_time() - c0)
        rows["pj_trace"].append(res.seconds)
        R_pj.append(res.reflectance_factor)
        c0, w0 = time.process_time(), time.perf_counter()
        img = np.asarray(mi.render(scene, seed=1000 + r))
        rows["mi_wall"].append(time.perf_counter() - w0)
        rows["mi_cpu"].append(time.process_time() - c0)
        R_mi.append(img[..., 0].reshape(args.resolution, m, args.resolution).mean(axis=(0, 2)))
        say(f"round {r + 1}/{args.rounds}: paintjax {res.rays / res.seconds:,.0f} paths/s ({rows['pj_wall'][-1]:.2f} s call), "
            f"mitsuba {paths_mi / rows['mi_wall'][-1]:,.0f} paths/s ({rows['mi_wall'][-1]:.2f} s), load {loads[-1]:.2f}")
    rays_pj = int(res.rays)

    # --- work per path
    t0 = time.perf_counter()
    sc = build_scene(array, geo, brdf, grid, n=n, clearcoat_thickness=h_c, primer_albedo=PRIMER_ALBEDO, min_cells=opt.cells_per_step,
                     mis=opt.mis)
    counted = plain_trace_counts(sc, opt, seed=7, rays=args.count_rays, batch=min(opt.lanes, args.count_rays))
    same = trace(array, geo, brdf, rays=args.count_rays, seed=7, **kw)  # the wavefront's paths for the same seed and ray ids
    t_count_pj = time.perf_counter() - t0
    pp = counted["per_path"]
    t0 = time.perf_counter()
    jit = not variant.startswith("scalar")
    walk_paths = args.count_paths if jit else min(args.count_paths, 16384)
    tile = tuple(float(t) for t in array.tile)
    if jit:
        walk, value, x = mitsuba_walk(mi, dr, scene, walk_paths, 7, tile)
    else:
        parts = [mitsuba_walk(mi, dr, scene, 1, 7 + i, tile) for i in range(walk_paths)]
        walk = {k: sum(p[0][k] for p in parts) for k in parts[0][0]}
        value, x = np.concatenate([p[1] for p in parts]), np.concatenate([p[2] for p in parts])
    t_count_mi = time.perf_counter() - t0
    wp = {k: v / walk_paths for k, v in walk.items()}
    wp["interior_casts"] = wp["casts"] - wp["camera"] - wp["escapes"]
    say(f"counting: paintjax {t_count_pj:.1f} s, mitsuba {t_count_mi:.1f} s")

    # --- summary
    to_R = 1.0 / (np.cos(np.deg2rad(45.0)) * np.sin(np.deg2rad(CONE_DEG)) ** 2)  # π L / E for a unit-radiance 2° disc at 45°
    replica_L = [float(np.mean(value[(x * m).astype(int) == j])) for j in range(m)]
    pj_rate = rays_pj / np.asarray(rows["pj_trace"])
    pj_call_rate = rays_pj / np.asarray(rows["pj_wall"])
    pj_cpu_rate = rays_pj / np.asarray(rows["pj_cpu"])
    mi_rate = paths_mi / np.asarray(rows["mi_wall"])
    mi_cpu_rate = paths_mi / np.asarray(rows["mi_cpu"])
    seg_pj, sh_pj = pp["segments"], pp["shadow_rays"]
    seg_mi, sh_mi = wp["casts"], wp["shadow_rays"]
    med = lambda a: float(np.median(a))  # noqa: E731
    out = {
        "benchmark": "peer_mitsuba",
        "date": date.today().isoformat(),
        "brdf": args.brdf,
        "machine": machine(),
        "load_before": list(load_before),
        "load_per_round": loads,
        "load_after": list(os.getloadavg()),
        "args": vars(args),
        "scene": {
            "sample": "silver1", "array_seed": 0, "platelets": int(len(c)), "tile_um": [float(t) for t in array.tile],
            "thickness_um": float(array.thickness), "basecoat_um": float(array.basecoat_thickness), "clearcoat_um": h_c, "n": n,
            "primer_albedo": PRIMER_ALBEDO, "illumination_deg": 45.0,
            "detectors_aspecular_deg": np.asarray(geo.aspecular_deg, float).tolist(),
            "paintjax_detector_cone_deg": float(geo.detector_aperture_deg), "mitsuba_emitter_cone_deg": CONE_DEG,
            "mitsuba_mesh": {"tiles": (2 * IMAGES + 1) ** 2, "boxes": int(len(faces) // 12), "triangles": int(len(faces))},
            "boxes_outside_basecoat": int(np.sum(np.any((verts[:, 2] < -1e-6) | (verts[:, 2] > array.basecoat_thickness + 1e-6), axis=-1))),
        },
        "paintjax": {
            "tracer": "paintjax.tracer.trace (wavefront, forward: reverse_share 0)", "lanes": opt.lanes, "paths_per_round": rays_pj,
            "warmup_s": t_pj_warm, "trace_s": spread(rows["pj_trace"]), "call_s": spread(rows["pj_wall"]), "cpu_s": spread(rows["pj_cpu"]),
            "paths_per_s": spread(pj_rate), "paths_per_s_whole_call": spread(pj_call_rate), "paths_per_cpu_s": spread(pj_cpu_rate),
            "work_source": "plain_trace_counts: the plain vmap(while_loop) tracer, same path physics and random numbers as trace",
            "counted_paths": int(counted["rays"]), "per_path": pp,
            "counted_R_plain": counted["reflectance_factor"].tolist(), "counted_R_wavefront": np.asarray(same.reflectance_factor).tolist(),
            "segments_per_s": med(pj_rate) * seg_pj, "rays_incl_shadow_per_s": med(pj_rate) * (seg_pj + sh_pj),
            "segments_per_cpu_s": med(pj_cpu_rate) * seg_pj,
            "randomize_azimuth": opt.randomize_azimuth, "R": np.mean(R_pj, axis=0).tolist(),
        },
        "mitsuba": {
            "version": mi.__version__, "variant": variant, "integrator": f"path, max_depth {MAX_DEPTH}, rr_depth {RR_DEPTH}",
            "sensor": f"batch of {m} orthographic cameras (MA98 directions), {args.resolution}² px each, box filter",
            "spp": args.spp, "paths_per_round": paths_mi, "scene_load_s": t_load, "warmup_s": t_mi_warm,
            "render_s": spread(rows["mi_wall"]), "cpu_s": spread(rows["mi_cpu"]),
            "paths_per_s": spread(mi_rate), "paths_per_cpu_s": spread(mi_cpu_rate),
            "work_source": "Python/Dr.Jit replica of the path integrator's loop on the same scene",
            "counted_paths": walk_paths, "per_path": wp,
            "segments_per_s": med(mi_rate) * seg_mi, "interior_segments_per_s": med(mi_rate) * wp["interior_casts"],
            "rays_incl_shadow_per_s": med(mi_rate) * (seg_mi + sh_mi), "segments_per_cpu_s": med(mi_cpu_rate) * seg_mi,
            "R": (to_R * np.mean(R_mi, axis=0)).tolist(), "R_replica": (to_R * np.asarray(replica_L)).tolist(),
            "vertices_beyond_block": walk["outside"] / max(1, walk["casts"] - walk["escapes"]),
        },
    }
    out["ratios_paintjax_over_mitsuba"] = {
        "paths_per_s": med(pj_rate) / med(mi_rate),
        "paths_per_cpu_s": med(pj_cpu_rate) / med(mi_cpu_rate),
        "segments_per_s": out["paintjax"]["segments_per_s"] / out["mitsuba"]["segments_per_s"],
        "segments_per_s_vs_interior": out["paintjax"]["segments_per_s"] / out["mitsuba"]["interior_segments_per_s"],
        "rays_incl_shadow_per_s": out["paintjax"]["rays_incl_shadow_per_s"] / out["mitsuba"]["rays_incl_shadow_per_s"],
        "segments_per_cpu_s": out["paintjax"]["segments_per_cpu_s"] / out["mitsuba"]["segments_per_cpu_s"],
    }
    out["seconds_total"] = time.perf_counter() - t_start
    tmp.cleanup()
    print(json.dumps(out))
    try:
        runs = json.loads(OUT.read_text())
        runs = runs if isinstance(runs, dict) and "runs" in runs else {"runs": {}}
    except (OSError, ValueError):
        runs = {"runs": {}}
    runs["runs"][args.brdf] = out
    runs["latest"] = args.brdf
    atomic_write_json(OUT, runs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
