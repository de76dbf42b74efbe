"""Content-hashed on-disk cache: hits are identical, corrupted or foreign files are rebuilt (issue 4)."""

import warnings

import numpy as np
import pytest

from paintjax._cache import CACHE_FORMAT_VERSION, cache_key, cache_path, cached_arrays, cached_json, default_cache_dir, save_cached
from paintjax.brdf._table import platelet_table_arrays


class Builder:
    def __init__(self, value=1.0):
        self.calls = 0
        self.value = value

    def __call__(self):
        self.calls += 1
        rng = np.random.default_rng(self.calls)
        return {"a": rng.normal(size=(4, 5)) * self.value, "b": np.arange(3, dtype=np.int32)}


INPUTS = {"sigma_um": 0.051, "tau_um": 0.64, "grid": np.linspace(0, 1, 5), "metal": 1.0 + 6.6j, "name": "x"}


def test_hit_returns_identical_arrays(tmp_path):
    build = Builder()
    first, hit1 = cached_arrays("t", INPUTS, build, folder=tmp_path)
    second, hit2 = cached_arrays("t", INPUTS, build, folder=tmp_path)
    assert (hit1, hit2) == (False, True) and build.calls == 1
    for k in first:
        assert second[k].dtype == first[k].dtype and np.array_equal(second[k], first[k])



def test_json_document_round_trip_and_entries_written_under_another_name(tmp_path):
    """`cached_json`: a document with NumPy values and NaN is built once and read back equal; an entry
    whose one array has another name (as the coverage study's rows were written) is read, not rebuilt."""
    calls = []

    def build():
        calls.append(1)
        return {"x": np.arange(3.0), "y": np.float64(0.5), "z": float("nan"), "s": "text"}

    first, hit0 = cached_json("doc", {"a": 1}, build, folder=tmp_path)
    again, hit1 = cached_json("doc", {"a": 1}, build, folder=tmp_path)
    assert (hit0, hit1) == (False, True) and len(calls) == 1
    assert first["x"] == [0.0, 1.0, 2.0] and first["y"] == 0.5 and np.isnan(first["z"]) and first["s"] == "text"
    assert again["x"] == first["x"] and np.isnan(again["z"])
    cached_arrays("legacy", {"b": 2}, lambda: {"row": np.asarray('{"v": 7}')}, folder=tmp_path)
    doc, hit = cached_json("legacy", {"b": 2}, lambda: calls.append(2) or {"v": 0}, folder=tmp_path)
    assert hit and doc == {"v": 7} and calls == [1]


def test_key_depends_on_every_input():
    k0 = cache_key("t", INPUTS)
    assert cache_key("t", dict(INPUTS)) == k0
    assert cache_key("t", INPUTS | {"sigma_um": 0.0510000001}) != k0
    assert cache_key("t", INPUTS | {"grid": np.linspace(0, 1, 6)}) != k0
    assert cache_key("u", INPUTS) != k0
    assert str(CACHE_FORMAT_VERSION)


@pytest.mark.parametrize("damage", ["truncate", "garbage", "empty"])
def test_corrupted_file_is_rebuilt(tmp_path, damage):
    build = Builder()
    cached_arrays("t", INPUTS, build, folder=tmp_path)
    path = cache_path("t", INPUTS, tmp_path)
    data = path.read_bytes()
    path.write_bytes({"truncate": data[: len(data) // 2], "garbage": b"not a zip" * 100, "empty": b""}[damage])
    with pytest.warns(UserWarning, match="rebuilding"):
        arrays, hit = cached_arrays("t", INPUTS, build, folder=tmp_path)
    assert not hit and build.calls == 2
    again, hit = cached_arrays("t", INPUTS, build, folder=tmp_path)  # the rebuilt file is trusted
    assert hit and np.array_equal(again["a"], arrays["a"])


def test_foreign_and_tampered_files_are_rebuilt(tmp_path):
    build = Builder()
    path = cache_path("t", INPUTS, tmp_path)
    other = INPUTS | {"sigma_um": 0.06}
    save_cached(path, "t", other, {"a": np.zeros((4, 5)), "b": np.zeros(3, np.int32)})  # another build's content
    with pytest.warns(UserWarning, match="another build"):
        arrays, hit = cached_arrays("t", INPUTS, build, folder=tmp_path)
    assert not hit and not np.all(arrays["a"] == 0)
    # tampered arrays with the original meta: the checksum catches it
    import io  # noqa: E401
    import json
    import zipfile

    with np.load(path) as z:
        meta, b = str(z["__meta__"]), z["b"]
    buf = io.BytesIO()
    np.savez(buf, __meta__=np.array(meta), a=np.ones((4, 5)), b=b)
    path.write_bytes(buf.getvalue())
    assert json.loads(meta)["key"] == cache_key("t", INPUTS) and zipfile.is_zipfile(path)
    with pytest.warns(UserWarning, match="checksum"):
        _, hit = cached_arrays("t", INPUTS, build, folder=tmp_path)
    assert not hit and build.calls == 2


def test_default_folder_from_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("PAINTJAX_CACHE", str(tmp_path / "c"))
    assert default_cache_dir() == tmp_path / "c"
    build = Builder()
    cached_arrays("t", INPUTS, build)
    assert cache_path("t", INPUTS).parent == tmp_path / "c" and cache_path("t", INPUTS).exists()
    monkeypatch.delenv("PAINTJAX_CACHE")
    assert default_cache_dir().name == "paintjax"


def test_no_temporary_files_left(tmp_path):
    cached_arrays("t", INPUTS, Builder(), folder=tmp_path)
    assert [p.name for p in tmp_path.iterdir()] == [cache_path("t", INPUTS, tmp_path).name]


def test_atomic_writes_get_the_usual_file_mode(tmp_path):
    """Written through a private temporary file, results still get mode 0666 & ~umask, like open() gives."""
    import os

    from paintjax._io import atomic_write_json

    mask = os.umask(0o022)
    os.umask(mask)  # (reading the umask means setting it)
    path = atomic_write_json(tmp_path / "r.json", {"a": 1})
    (tmp_path / "plain").write_text("x")
    assert path.stat().st_mode & 0o777 == (tmp_path / "plain").stat().st_mode & 0o777 == 0o666 & ~mask


def test_brdf_table_cache_hit_identical(tmp_path):
    kw = dict(source="kirchhoff", incidence_deg=[0.0, 20.0, 40.0], theta_s_deg=np.linspace(-89.5, 89.5, 181), cache_dir=tmp_path)
    a1, i1 = platelet_table_arrays(0.051, 0.64, **kw)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        a2, i2 = platelet_table_arrays(0.051, 0.64, **kw)
    assert not i1["cache_hit"] and i2["cache_hit"]
    assert a1.keys() == a2.keys()
    for k in a1:
        assert np.array_equal(np.asarray(a1[k]), a2[k]), k
    a3, i3 = platelet_table_arrays(0.051, 0.64, **(kw | {"method": "rotate"}))
    assert not i3["cache_hit"]


def test_compilation_cache_folder_follows_the_environment(monkeypatch, tmp_path):
    """`enable_compilation_cache`: `$JAX_COMPILATION_CACHE_DIR` when set, else `$PAINTJAX_CACHE/jax`."""
    import jax

    from paintjax import enable_compilation_cache

    before = jax.config.jax_compilation_cache_dir
    try:
        monkeypatch.setenv("PAINTJAX_CACHE", str(tmp_path / "c"))
        monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(tmp_path / "xla"))
        enable_compilation_cache()
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "xla")
        monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR")
        enable_compilation_cache()
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "c" / "jax")
    finally:
        jax.config.update("jax_compilation_cache_dir", before)
