"""Property-based bad input over the library's public entry points: random out-of-range, non-finite and
non-numeric values of each argument below.

Invariant: a ValueError whose message names the argument, raised before any work (every case here
would otherwise build a table, an array or trace rays, so a value that slipped through shows as a slow
test or a result instead of the error). Bounded: a few examples per argument. The hand-written cases
are in tests/test_bad_input.py; the CLI's in tests/test_fuzz_cli.py.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import paintjax


def _array():
    return paintjax.platelet_array_for_sample("silver1", 0, tile=110.0, pvc=0.05)


def _trace(**kw):
    return paintjax.trace(_array(), paintjax.ma98_geometry(45.0), paintjax.MirrorBRDF(), **({"rays": 64} | kw))


def _fit(**kw):
    forward = paintjax.make_forward("analytic")
    return paintjax.fit_least_squares(forward, [140.0, 110.0, 60.0, 35.0, 30.0], **kw)


#: (entry point, argument, its valid interval's ends (None: no upper end), whole numbers only, the call with that
#: argument set to a value): values outside the interval, NaN, ±inf and text must be refused by name.
CASES = [
    ("simulate", "sigma", 0.0, 10.0, False, lambda v: paintjax.simulate(sigma=v, rays=64)),
    ("simulate", "tau", 0.0, 100.0, False, lambda v: paintjax.simulate(tau=v, rays=64)),
    ("simulate", "pvc", 0.0, 0.4, False, lambda v: paintjax.simulate(pvc=v, rays=64)),
    ("simulate", "shape", 0.0, None, False, lambda v: paintjax.simulate(shape=v, rays=64)),
    ("simulate", "scale", 0.0, None, False, lambda v: paintjax.simulate(scale=v, rays=64)),
    ("simulate", "primer_albedo", 0.0, 1.0, False, lambda v: paintjax.simulate(primer_albedo=v, rays=64)),
    ("simulate", "waviness", 0.0, 15.0, False, lambda v: paintjax.simulate(waviness=v, rays=64)),
    ("simulate", "illumination", 0.0, 85.0, False, lambda v: paintjax.simulate(illumination_deg=v, rays=64)),
    ("simulate", "thickness", 1.0, None, False, lambda v: paintjax.simulate(thickness=v, rays=64)),
    ("simulate", "d50", 1.0, 50.0, False, lambda v: paintjax.simulate(d50=v, rays=64)),
    ("simulate", "rays", 32, 10**9, True, lambda v: paintjax.simulate(rays=v)),
    ("simulate", "seed", 0, None, True, lambda v: paintjax.simulate(seed=v, rays=64)),
    ("generate_platelet_array", "pvc", 0.0, 0.4, False, lambda v: paintjax.generate_platelet_array(0, pvc=v, tilt=(2.0, 2.0))),
    ("generate_platelet_array", "thickness", 0.0, 20.0, False,
     lambda v: paintjax.generate_platelet_array(0, pvc=0.1, tilt=(2.0, 2.0), thickness=v)),
    ("generate_platelet_array", "tile", 43.4, 5000.0, False, lambda v: paintjax.generate_platelet_array(0, pvc=0.1, tilt=(2.0, 2.0), tile=v)),
    ("generate_platelet_array", "max_attempts", 0, None, True,
     lambda v: paintjax.generate_platelet_array(0, pvc=0.1, tilt=(2.0, 2.0), max_attempts=v)),
    ("platelet_brdf_table", "sigma_um", 0.0, 10.0, False, lambda v: paintjax.platelet_brdf_table(v, 0.64)),
    ("platelet_brdf_table", "tau_um", 0.0, 100.0, False, lambda v: paintjax.platelet_brdf_table(0.05, v)),
    ("platelet_brdf_table", "wavelength_um", 0.2, 12.0, False, lambda v: paintjax.platelet_brdf_table(0.05, 0.64, wavelength_um=v)),
    ("trace", "rays", 32, 10**9, True, lambda v: _trace(rays=v)),
    ("trace", "primer_albedo", 0.0, 1.0, False, lambda v: _trace(primer_albedo=v)),
    ("trace", "clearcoat_thickness", 0.0, None, False, lambda v: _trace(clearcoat_thickness=v)),
    ("trace", "n", 1.0, 3.0, False, lambda v: _trace(n=v)),
    ("fit_least_squares", "n_starts", 1, 1024, True, lambda v: _fit(n_starts=v)),
    ("fit_least_squares", "max_steps", 1, 10**6, True, lambda v: _fit(max_steps=v)),
    ("fit_least_squares", "instrument_sd", 0.0, None, False, lambda v: _fit(instrument_sd=v)),
]


def _invalid(lo, hi, integer):
    text = st.text(alphabet="abcxyz,;", min_size=1, max_size=5)
    if integer:
        parts = [st.integers(max_value=math.ceil(lo) - 1), text]
        if hi is not None:
            parts.append(st.integers(min_value=math.floor(hi) + 1))
        return st.one_of(parts)
    parts = [st.floats(max_value=lo, exclude_max=True, allow_nan=False, allow_infinity=True), st.just(math.nan), text]
    if hi is not None:
        parts.append(st.floats(min_value=hi, exclude_min=True, allow_nan=False, allow_infinity=True))
    return st.one_of(parts)


@pytest.mark.parametrize("entry,argument,lo,hi,integer,call", CASES, ids=[f"{e}-{a}" for e, a, *_ in CASES])
def test_out_of_range_arguments_are_refused_by_name(entry, argument, lo, hi, integer, call):
    @settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True)
    @given(value=_invalid(lo, hi, integer))
    def case(value):
        with pytest.raises(ValueError) as err:
            call(value)
        assert argument in str(err.value), (entry, argument, value, str(err.value))

    case()
