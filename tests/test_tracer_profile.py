"""The wavefront step's time profile (`profile_wavefront_step`) on a tiny scene: structural truths of its
timings, and its argument checks."""

from __future__ import annotations

import math

import pytest

from paintjax import BeckmannBRDF, GammaTilt, boolean_platelet_array, ma98_geometry
from paintjax.tracer import PROFILE_STAGES, profile_wavefront_step

#: Stages timed directly (the rest are differences of these, which timing noise may push below zero).
MEASURED = ("traversal", "brdf_sample", "brdf_evaluate", "brdf_pdf", "brdf", "step", "shadows", "refill", "host", "full_step",
            "loop_all_steps")


def scene():
    array = boolean_platelet_array(0, 60, tile=(60.0, 60.0), basecoat_thickness=15.0, width=10.0, thickness=1.0, tilt=GammaTilt(2.29, 2.18))
    return array, ma98_geometry(45.0), BeckmannBRDF(0.05, 1.0, n_medium=1.5)


@pytest.fixture(scope="module")
def profile():
    array, geometry, brdf = scene()
    return profile_wavefront_step(array, geometry, brdf, lanes=256, rays=256 * 16, repeats=3, warm_calls=1)


def test_times_are_positive_and_finite(profile):
    s = profile["seconds"]
    assert set(s) == set(PROFILE_STAGES) == set(profile["fractions"]) == set(profile["labels"]) >= set(profile["parents"])
    assert all(s[k] > 0 and math.isfinite(s[k]) for k in MEASURED), s
    assert all(math.isfinite(v) for v in s.values()) and profile["call_overhead"] > 0


def test_the_loop_is_accounted_for_by_its_parts(profile):
    """The accounting identities of the profile. How the separately timed stages compare with the step is
    a measurement (benchmarks/tracer_profile.py), not a test: on a loaded machine the BRDF calls timed on
    their own have taken 1.7 × the whole step."""
    s, f = profile["seconds"], profile["fractions"]
    assert f["full_step"] == 1.0
    assert f["step"] + f["shadows"] + f["loop_overhead"] == pytest.approx(1.0)
    assert s["loop_overhead"] == pytest.approx(s["refill"] + s["host"] + s["loop_other"])


def test_counts_describe_a_mixed_wavefront(profile):
    c = profile["counts"]
    assert profile["lanes"] == 256 and profile["bidirectional"] and profile["loop_steady_calls"] >= 1
    assert 0.0 < c["lanes_alive"] <= 1.0 and c["lane_steps_max"] >= 1
    parts = c["lanes_platelet_hit"] + c["lanes_primer"] + c["lanes_interface"] + c["lanes_cells_only"]
    assert parts == pytest.approx(c["lanes_alive"])  # every live lane does exactly one of the four
    assert c["detectors"] == 5 and 0 <= c["shadow_rays_pending"] <= 256 * 5
    assert set(profile["not_isolated"]) >= {"compaction", "xla_while_loop"}


@pytest.mark.parametrize("kwargs,name", [(dict(lanes=0), "lanes"), (dict(lanes=-8), "lanes"), (dict(lanes=4), "lanes"),
                                         (dict(lanes=2.5), "lanes"), (dict(repeats=0), "repeats"), (dict(warm_calls=0), "warm_calls"),
                                         (dict(lanes=64, rays=10), "rays"), (dict(n=0.5), "index n")])
def test_bad_arguments_are_refused(kwargs, name):
    array, geometry, brdf = scene()
    with pytest.raises(ValueError, match=name):
        profile_wavefront_step(array, geometry, brdf, **kwargs)
