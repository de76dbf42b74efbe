"""Content-hashed on-disk cache of arrays (BRDF tables and other slow builds).

A build is described by a `kind` and a JSON-able dict of its inputs. The key is the SHA-256 of the
canonical JSON of (format version, kind, inputs); the file `<folder>/<kind>-<key[:24]>.npz` holds
the arrays plus a `__meta__` record (format version, kind, full key, inputs, SHA-256 of the array
bytes). A file whose meta or checksum does not match — truncated, corrupted, written by another
format version or holding another build — is not trusted: it is rebuilt and atomically replaced.

Default folder: `$PAINTJAX_CACHE`, else `~/.cache/paintjax`.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import warnings
import zipfile
from pathlib import Path
from typing import Callable

import numpy as np

from ._io import atomic_write_bytes, nearest_existing

#: Bump when the stored layout or the meaning of cached arrays changes.
CACHE_FORMAT_VERSION = 1


def default_cache_dir() -> Path:
    """`$PAINTJAX_CACHE` if set, else `~/.cache/paintjax`."""
    env = os.environ.get("PAINTJAX_CACHE")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "paintjax"


def enable_compilation_cache() -> None:
    """Persist XLA compilations under `$JAX_COMPILATION_CACHE_DIR` when set, else `default_cache_dir()/jax`,
    so repeat CLI runs skip compilation (an optimisation only: JAX falls back to compiling when the cache is
    unusable). Every compilation persists, the short ones too: a warm `paintjax table1` makes about 190 of
    them, 4–5 s in all, and reads them back in a fraction of that."""
    import jax

    jax.config.update("jax_compilation_cache_dir", os.environ.get("JAX_COMPILATION_CACHE_DIR") or str(default_cache_dir() / "jax"))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


def _canonical(obj):
    if isinstance(obj, dict):
        return {str(k): _canonical(v) for k, v in sorted(obj.items(), key=lambda kv: str(kv[0]))}
    if isinstance(obj, (list, tuple)):
        return [_canonical(v) for v in obj]
    if isinstance(obj, complex):
        return {"re": repr(obj.real), "im": repr(obj.imag)}
    if isinstance(obj, (float, np.floating)):
        return repr(float(obj))
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if hasattr(obj, "__array__"):
        a = np.asarray(obj)
        return {"dtype": str(a.dtype), "shape": list(a.shape), "sha256": hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()}
    if obj is None or isinstance(obj, str):
        return obj
    raise TypeError(f"cache inputs must be JSON-able numbers, strings, lists, dicts or arrays; got {type(obj).__name__}")


def cache_key(kind: str, inputs: dict) -> str:
    """SHA-256 hex key of (format version, kind, inputs)."""
    blob = json.dumps({"format": CACHE_FORMAT_VERSION, "kind": kind, "inputs": _canonical(inputs)}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def _arrays_digest(arrays: dict) -> str:
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(name.encode() + str(a.dtype).encode() + str(a.shape).encode() + a.tobytes())
    return h.hexdigest()


#: Results that ship with the package (read-only; `paintjax/data/cache`): a cache file missing from the
#: cache folder is read from here when a file of the same name, i.e. the same content key, ships.
SHIPPED_DIR = Path(__file__).parent / "data" / "cache"


def shipped(path: Path) -> Path:
    """`path` when it exists, else the shipped file of the same name when one ships, else `path`."""
    path = Path(path)
    if path.exists():
        return path
    candidate = SHIPPED_DIR / path.name
    return candidate if candidate.is_file() else path


def cache_path(kind: str, inputs: dict, folder: str | os.PathLike | None = None) -> Path:
    if folder is None:
        folder, name = default_cache_dir(), "the cache folder ($PAINTJAX_CACHE, default ~/.cache/paintjax)"
    else:
        folder, name = Path(folder), "cache_dir"
    probe = nearest_existing(folder)
    if not probe.is_dir():
        raise ValueError(f"{name} must be a folder, but {str(probe)!r} is a file")
    return folder / f"{kind}-{cache_key(kind, inputs)[:24]}.npz"


def _load(path: Path, kind: str, key: str) -> dict | None:
    """Arrays of a valid cache file, or None (with a warning) when it cannot be trusted."""
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["__meta__"]))
            arrays = {k: np.array(z[k]) for k in z.files if k != "__meta__"}
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError, json.JSONDecodeError) as err:
        warnings.warn(f"cache file {path} unreadable ({type(err).__name__}); rebuilding", stacklevel=3)
        return None
    if not isinstance(meta, dict) or meta.get("format") != CACHE_FORMAT_VERSION or meta.get("kind") != kind or meta.get("key") != key:
        warnings.warn(f"cache file {path} belongs to another build or format; rebuilding", stacklevel=3)
        return None
    if meta.get("sha256") != _arrays_digest(arrays):
        warnings.warn(f"cache file {path} failed its checksum; rebuilding", stacklevel=3)
        return None
    return arrays


def save_cached(path: Path, kind: str, inputs: dict, arrays: dict) -> Path:
    """Write arrays with their meta record atomically."""
    arrays = {k: np.asarray(v) for k, v in arrays.items()}
    meta = {"format": CACHE_FORMAT_VERSION, "kind": kind, "key": cache_key(kind, inputs), "inputs": _canonical(inputs), "sha256": _arrays_digest(arrays)}
    buf = io.BytesIO()
    np.savez(buf, __meta__=np.array(json.dumps(meta)), **arrays)
    return atomic_write_bytes(path, buf.getvalue())


def cached_arrays(
    kind: str,
    inputs: dict,
    build: Callable[[], dict],
    *,
    folder: str | os.PathLike | None = None,
    use_cache: bool = True,
) -> tuple[dict, bool]:
    """Arrays of a build, from the cache when a valid entry exists, else built and stored.

    Arguments:
        kind: short name of the build (part of the file name and of the key).
        inputs: everything the result depends on (numbers, strings, lists, dicts, arrays).
        build: zero-argument function returning a dict of arrays.
        folder: cache folder (default `default_cache_dir()`).
        use_cache: False builds without reading or writing the cache.

    Returns:
        (arrays, hit) — hit is True when the arrays came from the cache.
    """
    if not use_cache:
        return {k: np.asarray(v) for k, v in build().items()}, False
    path = cache_path(kind, inputs, folder)
    key = cache_key(kind, inputs)
    source = shipped(path)
    if source.exists():
        arrays = _load(source, kind, key)
        if arrays is not None:
            return arrays, True
    arrays = {k: np.asarray(v) for k, v in build().items()}
    save_cached(path, kind, inputs, arrays)
    return arrays, False


def cached_json(kind: str, inputs: dict, build: Callable[[], object], **kwargs) -> tuple[object, bool]:
    """A JSON document of a build, cached as `cached_arrays` caches arrays: the text is the entry's one
    array (read whatever its name, so entries written under another name stay valid).

    NumPy arrays and scalars in the document are stored as lists and numbers, NaN as JSON's NaN token.

    Returns:
        (document, hit) — hit is True when it came from the cache.
    """
    arrays, hit = cached_arrays(kind, inputs, lambda: {"json": np.asarray(json.dumps(build(), default=lambda o: np.asarray(o).tolist()))}, **kwargs)
    (text,) = arrays.values()
    return json.loads(str(text)), hit
