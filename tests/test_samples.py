"""The reference samples shipped with the package."""

import pytest

import paintjax as pj


def test_load_both_samples_with_uncertainties():
    s1, s2 = pj.load_sample("silver1"), pj.load_sample("Silver #2")
    assert s1.L_star == (143.3, 107.2, 58.6, 37.2, 32.1)
    assert s2.L_star == (129.0, 106.1, 67.7, 43.7, 36.2)
    assert s1.L_star_uncertainty == (0.3,) * 5
    assert (s1.tilt_shape.value, s1.tilt_shape.uncertainty) == (2.29, 0.05)
    assert (s2.tilt_scale.value, s2.tilt_scale.uncertainty) == (2.10, 0.03)
    assert s1.sigma == pj.Measured(0.051, 0.010) and s1.tau == pj.Measured(0.640, 0.110)
    assert s1.pvc.value == 0.20 and s1.basecoat_thickness == 20.0 and s1.clearcoat_thickness == 50.0
    assert s1.binder_index == 1.5 and s1.platelet_thickness == 1.0
    assert (s1.size_d10, s1.size_d50, s1.size_d90) == (8.0, 16.0, 30.0)
    assert s1.aspecular_deg == pj.STANDARD_ASPECULAR
    assert s1.mean_tilt_deg == pytest.approx(2.29 * 2.18)


def test_unknown_sample_lists_known_names():
    with pytest.raises(ValueError, match="silver1, silver2"):
        pj.load_sample("gold")
