"""Property-based bad input over the CLI: random out-of-range, non-finite and non-numeric values.

For every sub-command and numeric option below, Hypothesis draws values outside the option's valid
range (and text that is not a number). Invariants: exit status 2, one line on stderr that names the
option, no traceback, no output folder created. Bounded: a few examples per option, well under a
minute on 2 cores (every case must be refused before any work).
"""

from __future__ import annotations

import math

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from paintjax.cli._main import main

#: (command, option, valid interval's lower and upper end (None: no upper end), extra arguments):
#: values below the lower end or above the upper end are invalid (the ends themselves are not drawn).
RANGES = [
    ("lobe", "--sigma", 0.0, 10.0, []),
    ("lobe", "--tau", 0.0, 100.0, []),
    ("lobe", "--wavelength", 0.2, 12.0, []),
    ("lobe", "--n", 1.0, 5.0, []),
    ("lobe", "--step", 0.01, 10.0, []),
    ("brdf", "--sigma", 0.0, 10.0, []),
    ("brdf", "--tau", 0.0, 100.0, []),
    ("brdf", "--n", 1.0, 5.0, []),
    ("microfacet", "--shape", 0.0, None, []),
    ("microfacet", "--scale", 0.0, None, []),
    ("microfacet", "--n", 1.0, 3.0, []),
    ("microfacet", "--reflectance", 0.0, 1.0, []),
    ("simulate", "--primer-albedo", 0.0, 1.0, []),
    ("simulate", "--shape", 0.0, None, []),
    ("simulate", "--waviness", 0.0, 15.0, []),
    ("simulate", "--rays", 32.0, 1e9, []),
    ("simulate", "--pvc", 0.0, 0.4, []),
    ("simulate", "--tau", 0.0, 100.0, []),
    ("gonio", "--tau", 0.0, 100.0, []),
    ("array", "--max-attempts", 0.0, None, ["--no-plots"]),
    ("array", "--tile", 0.0, 5000.0, ["--no-plots"]),
    ("lobe", "--profiles", 1.0, 2000.0, []),
    ("design", "--starts", 1.0, 1024.0, ["--target", "140,110,60,35,30"]),
    ("design", "--tolerance", 0.0, None, ["--target", "140,110,60,35,30"]),
    ("fit", "--starts", 1.0, 1024.0, []),
    ("fit", "--max-steps", 1.0, 1e7, []),
    ("fit", "--walkers", 2.0, None, ["--posterior"]),
    ("fit", "--tilt-platelets", 0.0, 1e6, ["--posterior", "--inputs", "rq"]),
    ("table1", "--target-se", 0.0, None, []),
    ("table1", "--waviness", 0.0, 15.0, []),
    ("demo", "--seed", 0.0, None, []),
    ("posterior", "--walkers", 2.0, 4096.0, []),
    ("posterior", "--min-ess", 0.0, None, []),
    ("render", "--resolution", 16.0, 4096.0, ["--sample", "silver1"]),
    ("render", "--spp", 1.0, 65536.0, ["--sample", "silver1"]),
    ("render", "--seed", 0.0, 2.0**32 - 1, ["--sample", "silver1"]),
]


#: Options that take integers: drawn as integers outside the range (and as text).
INTEGER_OPTIONS = {"--rays", "--max-attempts", "--starts", "--max-steps", "--walkers", "--tilt-platelets", "--profiles", "--seed",
                   "--resolution", "--spp"}


def _invalid(option, lo, hi):
    text = st.text(alphabet="abcxyz,;", min_size=1, max_size=5)
    if option in INTEGER_OPTIONS:
        parts = [st.integers(max_value=math.ceil(lo) - 1).map(str), text]
        if hi is not None:
            parts.append(st.integers(min_value=math.floor(hi) + 1).map(str))
        return st.one_of(parts)
    below = st.floats(max_value=lo, exclude_max=True, allow_nan=False, allow_infinity=True)
    parts = [below.map(repr), st.just("nan"), text]
    if hi is not None:
        parts += [st.floats(min_value=hi, exclude_min=True, allow_nan=False, allow_infinity=True).map(repr)]
    return st.one_of(parts)


def _check(argv, option, tmp_path, capsys):
    out = tmp_path / "out"
    code = main(argv + (["--out", str(out)] if argv[0] not in ("microfacet", "design", "demo") else []))
    err = capsys.readouterr().err
    assert code == 2, (argv, code, err)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert option.lstrip("-").replace("-", "_") in lines[0].replace("-", "_"), (option, lines[0])
    assert not out.exists()


@pytest.mark.parametrize("command,option,lo,hi,extra", RANGES, ids=[f"{c}{o}" for c, o, *_ in RANGES])
def test_out_of_range_options_are_refused(command, option, lo, hi, extra, tmp_path_factory, capsys):
    @settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture], derandomize=True)
    @given(value=_invalid(option, lo, hi))
    def case(value):
        _check([command, *extra, f"{option}={value}"], option, tmp_path_factory.mktemp("f"), capsys)

    case()


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture], derandomize=True)
@given(shape=st.floats(0.05, 50.0), scale=st.floats(0.05, 20.0), n=st.floats(1.0, 3.0, exclude_min=True), reflectance=st.floats(0.0, 1.0))
def test_edge_valid_microfacet_gives_finite_json(shape, scale, n, reflectance, capsys):
    """Valid values up to the edges of their ranges: exit 0 and standard JSON without NaN (undefined values
    would be null, never NaN); L* finite and ≥ 0 at every angle."""
    import json

    code = main(["microfacet", "--shape", repr(shape), "--scale", repr(scale), "--n", repr(n), "--reflectance", repr(reflectance), "--json"])
    captured = capsys.readouterr()
    if code == 2:  # a law with no mass below 90° is refused by name, not computed
        assert "tilt gamma law" in captured.err and "Traceback" not in captured.err
        return
    assert code == 0, captured.err
    out = json.loads(captured.out)
    assert "NaN" not in captured.out and all(v is not None and math.isfinite(v) and v >= 0 for v in out["L_star"])


def _finite_numbers(obj) -> bool:
    if isinstance(obj, dict):
        return all(_finite_numbers(v) for v in obj.values())
    if isinstance(obj, list):
        return all(_finite_numbers(v) for v in obj)
    return isinstance(obj, (int, float)) and math.isfinite(obj)


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture], derandomize=True)
@example(wavelength=12.0, n=1.0, sigma=0.051, profiles=2, step=0.01)  # the far corners, whatever the four draws are:
@example(wavelength=0.2, n=5.0, sigma=1e-4, profiles=1, step=10.0)  # τ and --length set by the grid and the beam
@given(wavelength=st.sampled_from([0.2, 12.0, 0.5]), n=st.sampled_from([1.0, 5.0, 1.5]), sigma=st.sampled_from([1e-4, 0.051]),
       profiles=st.sampled_from([1, 2]), step=st.sampled_from([10.0, 0.01]))
def test_edge_valid_lobe_gives_finite_json_and_its_plot(wavelength, n, sigma, profiles, step, tmp_path_factory, capsys):
    """`lobe` at the ends of its ranges with the smallest sizes they allow (τ two grid steps, --length the shortest
    the tapered beam and τ accept): exit 0, standard JSON with every number finite, energy conserved, the plot
    written whole; or, for a surface the solver cannot converge, one line naming the fix (exit 2)."""
    import json

    tau = max(0.64, 2.5 * wavelength / (12.0 * n))  # two grid steps of the default grid λ0/(12 n)
    length = 1.01 * max(4.0 * tau, 20.0 * wavelength / (2.0 * math.pi * n))
    out = tmp_path_factory.mktemp("lobe")
    argv = ["lobe", "--wavelength", repr(wavelength), "--n", repr(n), "--sigma", repr(sigma), "--tau", repr(tau), "--length", repr(length),
            "--profiles", str(profiles), "--step", repr(step), "--json", "--out", str(out)]
    code = main(argv)
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err and code in (0, 2), (argv, captured.err)
    if code == 2:
        assert len(captured.err.strip().splitlines()) == 1 and "not converged" in captured.err, (argv, captured.err)
        return
    data = json.loads(captured.out)
    assert _finite_numbers(data), argv
    assert data["energy"]["scattered"] + data["energy"]["absorbed"] == pytest.approx(1.0, abs=0.011), argv
    assert (out / "lobe.png").stat().st_size > 1000 and not list(out.glob(".*.tmp"))


def _largest_platelet(pvc, d50, platelet_thickness) -> tuple[float, float, float]:
    """Silver #1 with these overrides: (the smallest tile side `paintjax array` accepts, √2 × the largest width + t;
    the largest platelet's volume; the basecoat thickness)."""
    from paintjax import load_sample
    from paintjax._pipeline import array_overrides

    s = load_sample("silver1")
    kw = array_overrides(s, pvc=pvc, d50=d50, platelet_thickness=platelet_thickness)
    w, t = float(kw["sizes"].max_width), kw.get("thickness", s.platelet_thickness)
    return math.sqrt(2.0) * w + t, w * w * t, s.basecoat_thickness


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture], derandomize=True)
@example(pvc=0.4, d50=1.0, platelet_thickness=0.001, tile_factor=1.0)  # the densest, smallest, thinnest corner: too many platelets
@example(pvc=0.001, d50=50.0, platelet_thickness=19.0, tile_factor=1.5)  # the sparsest, widest, thickest corner: under one platelet
@example(pvc=0.4, d50=16.0, platelet_thickness=19.0, tile_factor=1.0)  # dense thick platelets: placed
@given(pvc=st.sampled_from([0.001, 0.4]), d50=st.sampled_from([1.0, 16.0, 50.0]), platelet_thickness=st.sampled_from([0.001, 1.0, 19.0]),
       tile_factor=st.sampled_from([1.0, 1.5]))
def test_edge_valid_array_gives_finite_json_and_its_pictures(pvc, d50, platelet_thickness, tile_factor, tmp_path_factory, capsys):
    """`array` at the ends of its ranges, in the smallest tile the widths allow (and 1.5 × that), with 50 re-placements per
    platelet (bounded time): exit 0 with standard JSON, every number finite, no overlap left, the PVC reached and both
    pictures written whole; or one line that names the flag to change (exit 2: more platelets than the generator
    takes, a PVC below half a platelet in that tile, or overlaps that could not be removed)."""
    import json

    smallest, largest_volume, basecoat = _largest_platelet(pvc, d50, platelet_thickness)
    tile = tile_factor * smallest * (1 + 1e-9)
    out = tmp_path_factory.mktemp("array")
    argv = ["array", "--pvc", repr(pvc), "--d50", repr(d50), "--platelet-thickness", repr(platelet_thickness), "--tile", repr(tile),
            "--max-attempts", "50", "--json", "--out", str(out)]
    code = main(argv)
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err and code in (0, 2), (argv, captured.err)
    if code == 2:  # progress lines, indented, may come first
        lines = [ln for ln in captured.err.strip().splitlines() if not ln.startswith("  ")]
        assert len(lines) == 1 and any(f in lines[0] for f in ("--pvc", "--tile", "--max-attempts", "--platelet-thickness")), (argv, lines)
        assert not list(out.glob("*.png")) and not list(out.glob(".*.tmp"))
        return
    data = json.loads(captured.out)
    assert _finite_numbers(data) and data["count"] >= 1 and data["overlaps_exact"] == 0, (argv, data)
    # the widths are drawn until their volume is closest to the target: within half the largest platelet of it
    assert abs(data["pvc"] - pvc) <= 0.5 * largest_volume / (tile * tile * basecoat) + 1e-12, (argv, data)
    pictures = sorted(out.glob("*.png"))
    assert len(pictures) == 2 and all(p.stat().st_size > 1000 for p in pictures) and not list(out.glob(".*.tmp")), pictures


@pytest.mark.parametrize("argv", [
    # grazing light on a wavy coat over a white primer, the widest platelets, sparse, the largest seed
    ["--brdf", "mirror", "--illumination", "85", "--aspecular=0,45,170", "--waviness", "15", "--primer-albedo", "1", "--pvc", "0.01",
     "--d50", "50", "--seed", str(2**62)],
    # the smoothest and the longest-correlated Kirchhoff platelets, thin and sparse in a thick basecoat over a black primer, lit
    # along the normal, seen at ±80°
    ["--brdf", "kirchhoff", "--sigma", "1e-4", "--tau", "100", "--primer-albedo", "0", "--thickness", "60", "--pvc", "0.001",
     "--platelet-thickness", "0.05", "--illumination", "1e-3", "--aspecular=-80,0,80"],
], ids=["grazing-wavy-wide", "smooth-sparse-thin"])
def test_edge_valid_simulate_gives_finite_results(argv, tmp_path, capsys):
    """`simulate` (64 rays) at corners of its ranges: exit 0 with finite L*, standard errors and reflectance factors and an
    energy ledger that closes, its JSON and plot written whole; or one line that names the option to change (exit 2)."""
    import json

    out = tmp_path / "sim"
    code = main(["simulate", *argv, "--rays", "64", "--json", "--out", str(out)])
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err and code in (0, 2), (argv, captured.err)
    if code == 2:
        lines = [ln for ln in captured.err.strip().splitlines() if ln.startswith("paintjax")]
        assert len(lines) == 1 and "--" in lines[0], (argv, captured.err)
        assert not list(out.glob("*.json")), argv
        return
    data = json.loads(captured.out)
    for key in ("L_star", "L_star_se", "reflectance_factor"):
        assert all(math.isfinite(v) and v >= 0 for v in data[key]), (key, data[key])
    assert sum(data["energy"].values()) == pytest.approx(1.0, abs=1e-6), data["energy"]
    assert json.loads((out / "simulate.json").read_text())["rays"] == data["rays"]
    assert (out / "simulate.png").stat().st_size > 1000 and not list(out.glob(".*.tmp"))
