"""Many panels: measured L* rows from a CSV file, one least-squares fit per panel, on Dask.

**Input.** A CSV file with a header: `id`, the L* columns `L15, L25, L45, L75, L110` (the MA98
in-plane aspecular angles of 45° illumination that the forward models cover; any three or more),
and optional per-angle instrument SDs `sd15, …, sd110` [L*] (default `INSTRUMENT_SD`). An empty
cell leaves that angle out of the panel's fit. A bad row (no id, a duplicate id, text or NaN in a
number, an L* outside [−5, 250], an SD ≤ 0, fewer than three angles) becomes a row of the results
with its error; it never stops the batch. A column the models do not cover (e.g. `L-15`) is an error
for the whole file.

**Execution.** Each panel is one Dask task (`fit_panel`): by default on a `LocalCluster` of worker
processes on this machine, or on an existing cluster given by its scheduler address (e.g. one
started by dask-jobqueue on Slurm). A worker that dies has its tasks retried by the scheduler.
Results stream back as they finish and the results table is rewritten after each one (temporary
file, then rename), so an interrupted batch keeps what it finished; a rerun with the same settings
skips the panels already fitted.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from .._io import atomic_path, nearest_existing

#: Aspecular angles a panel may give (45° illumination, the forward models' angles).
PANEL_ANGLES = (15, 25, 45, 75, 110)
#: Fewest angles of a panel.
MIN_ANGLES = 3
_MEASURED_RANGE = (-5.0, 250.0)


def read_panels(path, *, instrument_sd: float = 0.3) -> tuple[list[dict], list[dict]]:
    """Panels of a CSV file, and its bad rows.

    Arguments:
        path: the CSV file (see the module docstring for its columns).
        instrument_sd: SD of an angle without its own `sd` column or cell [L*].

    Returns:
        (panels, bad): panels as {"id", "L_star" (5,) with NaN where absent, "sd" (5,)}; bad rows as
        {"id", "row", "status": "error", "error"}; `row` counts data rows from 1.

    Raises:
        ValueError: the file cannot be read, has no `id` column, no L* column, or a column no forward model covers.
    """
    p = Path(path)
    if p.is_dir():
        raise ValueError(f"data must be a CSV file, but {str(p)!r} is a folder")
    if not p.is_file():
        raise ValueError(f"data file not found: {str(p)!r}")
    with open(p, newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        columns = [c.strip() for c in (reader.fieldnames or [])]
        rows = [{(k or "").strip(): (v or "").strip() for k, v in r.items()} for r in reader]
    if "id" not in columns:
        raise ValueError(f"data must have an 'id' column, got columns {columns}")
    known = {"id"} | {f"L{a}" for a in PANEL_ANGLES} | {f"sd{a}" for a in PANEL_ANGLES}
    unknown = [c for c in columns if c not in known]
    if unknown:
        raise ValueError(f"data columns {unknown} are not modelled: the columns are id, "
                         f"{', '.join(f'L{a}' for a in PANEL_ANGLES)} and optional sd15 … sd110 (45° illumination)")
    if not any(f"L{a}" in columns for a in PANEL_ANGLES):
        raise ValueError(f"data has no L* column ({', '.join(f'L{a}' for a in PANEL_ANGLES)})")
    panels, bad, seen = [], [], set()
    for i, row in enumerate(rows, start=1):
        pid = row.get("id", "")
        try:
            if not pid:
                raise ValueError("no id")
            if pid in seen:
                raise ValueError(f"duplicate id {pid!r}")
            seen.add(pid)
            L = np.full(len(PANEL_ANGLES), np.nan)
            sd = np.full(len(PANEL_ANGLES), float(instrument_sd))
            for j, a in enumerate(PANEL_ANGLES):
                text = row.get(f"L{a}", "")
                if text:
                    L[j] = _number(text, f"L{a}")
                    if not _MEASURED_RANGE[0] <= L[j] <= _MEASURED_RANGE[1]:
                        raise ValueError(f"L{a} must lie in [{_MEASURED_RANGE[0]:g}, {_MEASURED_RANGE[1]:g}], got {text!r}")
                text = row.get(f"sd{a}", "")
                if text:
                    sd[j] = _number(text, f"sd{a}")
                    if not sd[j] > 0:
                        raise ValueError(f"sd{a} must be > 0, got {text!r}")
            if int(np.isfinite(L).sum()) < MIN_ANGLES:
                raise ValueError(f"needs L* at {MIN_ANGLES} or more of the angles {list(PANEL_ANGLES)}, got {int(np.isfinite(L).sum())}")
        except ValueError as err:
            bad.append({"id": pid, "row": i, "status": "error", "error": str(err)})
            continue
        panels.append({"id": pid, "L_star": L, "sd": sd})
    return panels, bad


def _number(text: str, column: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise ValueError(f"{column} must be a number, got {text!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{column} must be finite, got {text!r}")
    return v


def settings_key(forward: str, free: Sequence[str], n_starts: int, seed: int) -> str:
    """Short hash of the fit settings: a rerun skips a panel only when its result has the same key."""
    text = json.dumps({"forward": forward, "free": list(free), "starts": int(n_starts), "seed": int(seed)}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


_FORWARDS: dict = {}


def fit_panel(panel: dict, forward: str, free: Sequence[str], n_starts: int, seed: int) -> dict:
    """Least-squares fit of one panel (a Dask task; also callable directly). Angles without L* get
    weight 0; an angle's own SD u_j enters as the weight s_j(0.3) / s_j(u_j), s² = u² + emulator error²."""
    import jax

    jax.config.update("jax_enable_x64", True)
    from ._fit import INSTRUMENT_SD, fit_least_squares
    from ._registry import make_forward

    key = (forward, tuple(free))
    if key not in _FORWARDS:  # once per worker process
        _FORWARDS[key] = make_forward(forward, tuple(free), {})
    fwd = _FORWARDS[key]
    L, sd = np.asarray(panel["L_star"], float), np.asarray(panel["sd"], float)
    have = np.isfinite(L)
    err2 = np.asarray(fwd.error_sd, float) ** 2
    weights = np.where(have, np.sqrt((INSTRUMENT_SD**2 + err2) / (sd**2 + err2)), 0.0)
    fr = fit_least_squares(fwd, np.where(have, L, 50.0), free=[n for n in free if n in fwd.parameter_names], weights=weights,
                           n_starts=n_starts, seed=seed)
    out = {"id": panel["id"], "status": "ok", "error": "", "converged": bool(fr.success), "chi2": float(fr.chi2), "dof": int(fr.dof),
           "p_value": fr.p_value, "at_bound": ";".join(fr.at_bound), "settings": settings_key(forward, free, n_starts, seed)}
    for name in fr.values:
        out[name], out[f"{name}_sd"] = float(fr.values[name]), float(fr.stderr[name])
    for j, a in enumerate(PANEL_ANGLES):
        out[f"L{a}_fit"] = float(fr.L_star_fit[j])
    return out


def _write_table(path: Path, rows: list[dict]) -> None:
    """All rows (union of their columns) to CSV, written atomically (`atomic_path`)."""
    columns: list[str] = []
    for r in rows:
        columns += [k for k in r if k not in columns]
    with atomic_path(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=columns)
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k, "")) for k in columns})


def read_results(path) -> list[dict]:
    """Rows of a results table written by `fit_panels` (strings as stored); [] when absent."""
    p = Path(path)
    if not p.exists():
        return []
    with open(p, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def fit_panels(
    data,
    out,
    *,
    forward: str = "tracer-emulator-wide",
    free: Sequence[str] = ("shape", "scale", "sigma", "tau"),
    n_starts: int = 8,
    seed: int = 0,
    scheduler: str | None = None,
    workers: int = 2,
    client=None,
    on_result: Callable[[dict, int, int], None] | None = None,
) -> list[dict]:
    """Fit every panel of a CSV file, one Dask task per panel, into a results CSV that resumes.

    Arguments:
        data: the panels' CSV file (`read_panels`).
        out: the results CSV; rows already there with the same settings are kept and not recomputed.
        forward, free, n_starts, seed: the fit (`fit_least_squares` through `make_forward`).
        scheduler: address of an existing Dask scheduler (default `$DASK_SCHEDULER_ADDRESS`, else a
            `LocalCluster` of `workers` processes on this machine).
        workers: worker processes of the local cluster.
        client: an existing `distributed.Client` (overrides `scheduler` and `workers`).
        on_result: called as `on_result(row, done, total)` as each result arrives (progress).

    Returns:
        The results rows: the panels in the order of the input file, then the bad rows with their errors.
    """
    try:
        from distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise ValueError("many panels run on Dask, which is not installed: pip install 'paintjax[batch]'") from None

    out = Path(out)
    if out.exists() and out.is_dir():
        raise ValueError(f"out must be a CSV file, but {str(out)!r} is a folder")
    probe = nearest_existing(out.parent)
    if not probe.is_dir() or not os.access(probe, os.W_OK | os.X_OK):
        raise ValueError(f"out {str(out)!r} cannot be written: {str(probe)!r} is not a writable folder")
    if int(workers) < 1:
        raise ValueError(f"workers must be >= 1, got {workers!r}")
    panels, bad = read_panels(data)
    key = settings_key(forward, free, n_starts, seed)
    done = {r["id"]: r for r in read_results(out) if r.get("status") == "ok" and r.get("settings") == key}
    results = {p["id"]: done[p["id"]] for p in panels if p["id"] in done}
    todo = [p for p in panels if p["id"] not in done]
    out.parent.mkdir(parents=True, exist_ok=True)

    def table():  # the panels in file order (those finished so far), then the bad rows
        return [results[p["id"]] for p in panels if p["id"] in results] + bad

    def write():
        _write_table(out, table())

    write()
    if todo:
        own = client is None
        address = scheduler or os.environ.get("DASK_SCHEDULER_ADDRESS")
        if own:
            client = Client(address) if address else Client(LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True,
                                                                            dashboard_address=None))
        try:
            futures = {client.submit(fit_panel, p, forward, tuple(free), int(n_starts), int(seed), key=f"fit-{key}-{p['id']}", pure=False): p
                       for p in todo}
            for n, fut in enumerate(as_completed(futures), start=1):
                p = futures[fut]
                try:
                    row = fut.result()
                except Exception as err:  # a panel whose fit fails is a row with its error, not the end of the batch
                    row = {"id": p["id"], "status": "error", "error": f"{type(err).__name__}: {err}"}
                results[p["id"]] = row
                write()
                if on_result is not None:
                    on_result(row, n, len(todo))
        finally:
            if own:
                cluster = getattr(client, "cluster", None)
                client.close()
                if cluster is not None:
                    cluster.close()
    return table()
