"""Bad input to the library's public entry points: a ValueError that names the argument and its range,
raised before any work; nothing written, nothing altered. (The CLI's cases: tests/test_cli.py and
tests/test_fuzz_cli.py.)"""

from __future__ import annotations

import math

import numpy as np
import pytest

import paintjax
from paintjax.inverse import check_chain


def _geometry():
    return paintjax.ma98_geometry(45.0, (15, 25, 45, 75, 110))


CASES = [
    ("reflectance_factor_to_lightness negative", lambda: paintjax.reflectance_factor_to_lightness(-1.0), "R must be a finite"),
    ("reflectance_factor_to_lightness NaN", lambda: paintjax.reflectance_factor_to_lightness(float("nan")), "R must be a finite"),
    ("reflectance_factor_to_lightness inf", lambda: paintjax.reflectance_factor_to_lightness([0.2, math.inf]), "R must be a finite"),
    ("reflectance_factor_to_lightness text", lambda: paintjax.reflectance_factor_to_lightness("0.5"), "R must be a finite"),
    ("reflectance_factor_to_lightness None", lambda: paintjax.reflectance_factor_to_lightness(None), "R must be a finite"),
    ("reflectance_factor_to_lightness complex", lambda: paintjax.reflectance_factor_to_lightness(0.5 + 1j), "real"),
    ("microfacet tilt None", lambda: paintjax.microfacet_reflectance_factor(_geometry(), None), "tilt must be a GammaTilt"),
    ("microfacet geometry None", lambda: paintjax.microfacet_reflectance_factor(None, paintjax.GammaTilt(2.0, 2.0)), "geometry must be a Geometry"),
    ("microfacet coat index", lambda: paintjax.microfacet_reflectance_factor(_geometry(), paintjax.GammaTilt(2.0, 2.0), n=0.9), "refractive index"),
    ("lobes sigma inf", lambda: paintjax.profile_averaged_lobes(math.inf, 0.6, incidence_deg=[0.0], theta_s_deg=[0.0]), "sigma_um"),
    ("lobes sigma negative", lambda: paintjax.profile_averaged_lobes(-0.1, 0.6, incidence_deg=[0.0], theta_s_deg=[0.0]), "sigma_um"),
    ("lobes tau NaN", lambda: paintjax.profile_averaged_lobes(0.05, math.nan, incidence_deg=[0.0], theta_s_deg=[0.0]), "tau_um"),
    ("lobes wavelength 15 µm", lambda: paintjax.profile_averaged_lobes(0.05, 0.6, wavelength_um=15.0, incidence_deg=[0.0], theta_s_deg=[0.0]),
     "wavelength_um must lie in [0.2, 12.0]"),
    ("lobes wavelength 1e-6 µm", lambda: paintjax.profile_averaged_lobes(0.05, 0.6, wavelength_um=1e-6, incidence_deg=[0.0], theta_s_deg=[0.0]),
     "wavelength_um must lie in [0.2, 12.0]"),
    ("lobes huge profile", lambda: paintjax.profile_averaged_lobes(0.05, 0.6, length_um=5000.0, incidence_deg=[0.0], theta_s_deg=[0.0]),
     "points on one profile"),
    ("lobes length NaN", lambda: paintjax.profile_averaged_lobes(0.05, 0.6, length_um=math.nan, incidence_deg=[0.0], theta_s_deg=[0.0]), "length_um"),
    ("brdf table sigma 0", lambda: paintjax.platelet_brdf_table(0.0, 0.6), "sigma_um"),
    ("brdf table tau inf", lambda: paintjax.platelet_brdf_table(0.05, math.inf), "tau_um"),
    ("gamma tilt shape", lambda: paintjax.GammaTilt(-1.0, 2.0), "shape"),
    ("geometry illumination", lambda: paintjax.ma98_geometry(0.0), "illumination_deg"),
]


@pytest.mark.parametrize("name,call,needle", CASES, ids=[c[0] for c in CASES])
def test_bad_input_names_the_argument(name, call, needle):
    with pytest.raises(ValueError, match=None) as err:
        call()
    assert needle in str(err.value), (name, str(err.value))


def test_check_chain_leaves_files_alone(tmp_path):
    """A folder, a text file, or a chain of another run: refused, and the file is unchanged."""
    with pytest.raises(ValueError, match="is a folder"):
        check_chain(tmp_path, "{}")
    notes = tmp_path / "notes.h5"
    notes.write_bytes(b"not an hdf5 file")
    with pytest.raises(ValueError, match="not a readable emcee chain"):
        check_chain(notes, "{}")
    assert notes.read_bytes() == b"not an hdf5 file"
    assert check_chain(tmp_path / "new.h5", "{}") is False and not (tmp_path / "new.h5").exists()


def test_profile_folder_and_units(tmp_path):
    from paintjax.wave import load_line_scan

    with pytest.raises(ValueError, match="is a folder"):
        load_line_scan(tmp_path)
    with pytest.raises(ValueError, match="units"):
        load_line_scan(tmp_path / "x.csv", units="furlong")
    with pytest.raises(ValueError, match="not found"):
        load_line_scan(tmp_path / "missing.csv")


def test_lightness_is_still_differentiable_and_jittable():
    import jax

    assert np.isfinite(float(jax.jit(paintjax.reflectance_factor_to_lightness)(0.3)))
    assert float(jax.grad(paintjax.reflectance_factor_to_lightness)(0.3)) > 0


# ------------------------------------------------------------------------------------------ property-based
from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

ANY_FLOAT = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**6, 10**6), st.text(max_size=4), st.none())


@settings(max_examples=60, deadline=None, derandomize=True)
@given(R=ANY_FLOAT)
def test_lightness_of_anything_is_a_finite_number_or_a_named_error(R):
    try:
        L = float(paintjax.reflectance_factor_to_lightness(R))
    except ValueError as err:
        assert str(err).startswith("R must be")
        return
    assert math.isfinite(L) and L >= 0.0


@settings(max_examples=40, deadline=None, derandomize=True)
@given(shape=ANY_FLOAT, scale=ANY_FLOAT)
def test_gamma_tilt_of_anything_is_valid_or_a_named_error(shape, scale):
    try:
        tilt = paintjax.GammaTilt(shape, scale)
    except ValueError as err:
        assert "shape" in str(err) or "scale" in str(err)
        return
    assert float(tilt.shape) > 0 and float(tilt.scale_deg) > 0


@settings(max_examples=40, deadline=None, derandomize=True)
@given(illumination=ANY_FLOAT)
def test_geometry_of_anything_is_valid_or_a_named_error(illumination):
    try:
        g = paintjax.ma98_geometry(illumination)
    except ValueError as err:
        assert "illumination" in str(err)
        return
    assert np.all(np.isfinite(np.asarray(g.detectors_air())))
