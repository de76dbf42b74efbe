"""The plain tracer's work counters (`plain_trace_counts`): consistent, and counting leaves the physics unchanged."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from paintjax import MirrorBRDF, build_grid, ma98_geometry
from paintjax.microstructure._array import boolean_platelet_array
from paintjax.tracer import TracerOptions, build_scene, plain_trace_counts
from paintjax.tracer._plain import COUNT_KEYS, _ray_program


def test_counts_are_consistent_and_leave_the_result_unchanged():
    arr = boolean_platelet_array(4, 150, tile=(40.0, 40.0), basecoat_thickness=20.0, width=4.0, thickness=1.0, tilt=(1.2, 20.0), margin=3.4)
    geo = ma98_geometry(45.0, detector_aperture_deg=2.0)
    opt = TracerOptions(shadow_roulette=0.0, reverse_share=0.0, lanes=256)  # every positive NEE value gets its shadow ray
    sc = build_scene(arr, geo, MirrorBRDF(n_binder=1.5), build_grid(arr, 5.0, capacity=24), n=1.5, clearcoat_thickness=50.0,
                     primer_albedo=0.3, min_cells=opt.cells_per_step, mis=opt.mis)
    rays, m = 384, geo.num_detectors
    out = plain_trace_counts(sc, opt, seed=1, rays=rays, batch=256)  # a partial last batch: ids 256 … 383 only
    per = dict(zip(COUNT_KEYS, out["per_ray"].T))
    tot = out["totals"]
    assert out["per_ray"].shape == (rays, len(COUNT_KEYS))
    assert np.all(per["segments"] >= 1) and np.all(per["steps"] >= per["segments"])
    assert tot["segments"] == tot["platelet_events"] + tot["primer_events"] + tot["interface_events"]
    assert np.array_equal(per["platelet_events"] + per["primer_events"], per["kernel_events"])  # the classification is the kernel's
    assert tot["platelet_events"] > 0 and tot["primer_events"] > 0 and tot["interface_events"] > 0
    # a mirror has no finite part: NEE (one shadow ray per detector) at the primer only, all of it positive
    assert np.array_equal(per["shadow_rays"], m * per["primer_events"])
    assert np.array_equal(per["nee_candidates"], m * per["kernel_events"])
    assert abs(out["per_path"]["segments"] - tot["segments"] / rays) < 1e-12
    # the counters change nothing: the plain tracer without them gives the same tallies
    off = np.asarray(_ray_program(sc, opt, 1)(jnp.arange(rays, dtype=jnp.int64)), dtype=float).sum(axis=0)
    np.testing.assert_allclose(out["tally"], off[: out["tally"].shape[0]], rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(out["reflectance_factor"], off[:m] / rays, rtol=1e-6, atol=1e-12)
