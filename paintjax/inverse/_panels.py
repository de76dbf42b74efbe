"""Many panels: measured L* rows from a CSV file, one fit (and optionally one posterior) per panel, on Dask.

**Input.** A CSV file with a header: `id`, the L* columns `L-15, L15, L25, L45, L75, L110` (the six
MA98 in-plane aspecular angles of 45° illumination; any three or more), optional per-angle
instrument SDs `sd-15, sd15, …, sd110` [L*] (default `INSTRUMENT_SD`), and optional
known inputs with their SDs, `shape, shape_sd, scale, scale_sd` (tilt law, scale in degrees),
`sigma, sigma_sd, tau, tau_sd` (roughness, µm) and `pvc, pvc_sd` (for forward models that have it):
each enters the panel's fit and posterior as a Gaussian term, value ± SD of the true parameter.
An empty cell leaves that angle or input out of the panel. A bad row (no id, a duplicate id, text
or NaN in a number, an L* outside [−5, 250], an SD ≤ 0, fewer than three angles, a known input
without its SD) becomes a row of the results with its error; it never stops the batch. A column that
is not one of these (e.g. `L80`, an angle of 15° illumination), L* at an angle the forward model does
not give (−15° with "tracer-emulator": only "tracer-emulator-wide" and the analytic models give it), or
a known input that is not a free parameter of the fit, is an error for the whole file.

**Angles.** A panel with L* at −15° is fitted with the forward model at all six angles; the others at
the standard five, so their numbers are those of a five-angle fit. Angles without L* have weight 0.

**Output.** One row per panel (`fit_panel`): least-squares estimates with SDs, χ², dof, p-value,
box-edge flags and the fitted L* (`L15_fit`, …; `L-15_fit` for a panel fitted at six angles); with a
posterior also 5/50/95 % quantiles, R-hat, bulk ESS, the
posterior-predictive p-value, the posterior's box-edge flags and each known input's shift (z).
`fit_panels` writes the table as CSV and NetCDF (one `panel` dimension) and a figure per panel.

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
from ._chain import MAX_RHAT, check_walkers

#: Aspecular angles a panel may give (MA98, 45° illumination): −15° and the standard five.
PANEL_ANGLES = (-15, 15, 25, 45, 75, 110)
#: The standard five, at which every panel is fitted.
STANDARD_ANGLES = (15, 25, 45, 75, 110)
#: Fewest angles of a panel.
MIN_ANGLES = 3
#: Parameters a row may give as known inputs (`name`, `name_sd` columns).
KNOWN_INPUTS = ("shape", "scale", "sigma", "tau", "pvc")
_MEASURED_RANGE = (-5.0, 250.0)
#: Columns of the results that hold text (the rest are numbers, NaN where absent).
TEXT_COLUMNS = ("status", "error", "at_bound", "settings", "posterior_edge")


def read_panels(path, *, instrument_sd: float = 0.3) -> tuple[list[dict], list[dict]]:
    """Panels of a CSV file, and its bad rows.

    Arguments:
        path: the CSV file (see the module docstring for its columns).
        instrument_sd: SD of an angle without its own `sd` column or cell [L*].

    Returns:
        (panels, bad): panels as {"id", "L_star" (6,) at `PANEL_ANGLES` with NaN where absent, "sd" (6,), "known"
        {name: (value, sd)}}; bad rows as {"id", "row", "status": "error", "error"}; `row` counts data
        rows from 1.

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
    allowed = {"id"} | {f"L{a}" for a in PANEL_ANGLES} | {f"sd{a}" for a in PANEL_ANGLES} | set(KNOWN_INPUTS) | {f"{n}_sd" for n in KNOWN_INPUTS}
    unknown = [c for c in columns if c not in allowed]
    if unknown:
        raise ValueError(f"data columns {unknown} are not modelled: the columns are id, "
                         f"{', '.join(f'L{a}' for a in PANEL_ANGLES)}, optional sd-15 … sd110 (45° illumination) and optional known "
                         f"inputs {', '.join(KNOWN_INPUTS)} with their *_sd")
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
            known = {}
            for name in KNOWN_INPUTS:
                value, sd_text = row.get(name, ""), row.get(f"{name}_sd", "")
                if value or sd_text:
                    if not (value and sd_text):
                        raise ValueError(f"known input {name} needs both {name} and {name}_sd, got {value!r} and {sd_text!r}")
                    v, u = _number(value, name), _number(sd_text, f"{name}_sd")
                    if not u > 0:
                        raise ValueError(f"{name}_sd must be > 0, got {sd_text!r}")
                    known[name] = (v, u)
        except ValueError as err:
            bad.append({"id": pid, "row": i, "status": "error", "error": str(err)})
            continue
        panels.append({"id": pid, "L_star": L, "sd": sd, "known": known})
    return panels, bad


def check_angles(panels: list[dict], forward: str) -> None:
    """ValueError, naming the model and the angles, where panels give L* at angles the forward model does not give."""
    from ._registry import forward_angles

    covered = forward_angles(forward)
    missing = [a for j, a in enumerate(PANEL_ANGLES) if a not in covered and any(np.isfinite(p["L_star"][j]) for p in panels)]
    if missing:
        raise ValueError(f"data columns {[f'L{a}' for a in missing]} hold L* at {', '.join(f'{a}°' for a in missing)}, which the forward "
                         f"model {forward!r} does not give (it gives {', '.join(f'{a:g}°' for a in covered)}; 'tracer-emulator-wide' "
                         "gives -15° too)")


def _number(text: str, column: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise ValueError(f"{column} must be a number, got {text!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{column} must be finite, got {text!r}")
    return v


def settings_key(forward: str, free: Sequence[str], n_starts: int, seed: int, posterior: dict | None = None) -> str:
    """Short hash of the fit settings: a rerun skips a panel only when its result has the same key."""
    text = json.dumps({"forward": forward, "free": list(free), "starts": int(n_starts), "seed": int(seed)}
                      | ({"posterior": posterior} if posterior else {}), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


_FORWARDS: dict = {}


def fit_panel(panel: dict, forward: str, free: Sequence[str], n_starts: int, seed: int, posterior: dict | None = None) -> dict:
    """Least-squares fit of one panel, and optionally its posterior (a Dask task; also callable directly).

    Arguments:
        panel: a panel of `read_panels`: angles without L* are left out, each angle has its own
            instrument SD, known inputs enter as Gaussian terms (`fit_least_squares(priors=)`,
            `KnownInputs`).
        forward, free, n_starts, seed: the fit (`make_forward`, `fit_least_squares`).
        posterior: None (least squares only) or the `sample_posterior` settings {"walkers",
            "max_steps", "min_ess"} and optionally "max_rhat" (default `MAX_RHAT`, 1.01); the model discrepancy δ is sampled.

    Returns:
        The results row (module docstring).
    """
    import jax

    jax.config.update("jax_enable_x64", True)
    from .._cache import enable_compilation_cache
    from ._fit import fit_least_squares
    from ._registry import make_forward

    L = np.asarray(panel["L_star"], float)
    angles = tuple(a for a, x in zip(PANEL_ANGLES, L) if a in STANDARD_ANGLES or np.isfinite(x))
    cols = [PANEL_ANGLES.index(a) for a in angles]
    key = (forward, tuple(free), angles)
    if key not in _FORWARDS:  # once per worker process; XLA compilations persist across workers and runs
        enable_compilation_cache()
        extra = {} if angles == STANDARD_ANGLES else {"angles": angles}
        _FORWARDS[key] = make_forward(forward, tuple(free), {}, **extra)
    fwd = _FORWARDS[key]
    L, sd = L[cols], np.asarray(panel["sd"], float)[cols]
    have = np.isfinite(L)
    names = [n for n in free if n in fwd.parameter_names]
    known = dict(panel.get("known") or {})
    fr = fit_least_squares(fwd, np.where(have, L, 50.0), free=names, weights=have.astype(float), instrument_sd=sd, n_starts=n_starts,
                           seed=seed, priors=known or None)
    out = {"id": panel["id"], "status": "ok", "error": "", "converged": bool(fr.success), "chi2": float(fr.chi2), "dof": int(fr.dof),
           "p_value": fr.p_value, "at_bound": ";".join(fr.at_bound), "settings": settings_key(forward, free, n_starts, seed, posterior)}
    for name in fr.values:
        out[name], out[f"{name}_sd"] = float(fr.values[name]), float(fr.stderr[name])
    for j, a in enumerate(angles):
        out[f"L{a}_fit"] = float(fr.L_star_fit[j])
    if posterior:
        out |= _panel_posterior(fwd, names, L, sd, have, known, fr, posterior, seed, angles)
    return out


def _panel_posterior(fwd, names, L, sd, have, known, fr, settings: dict, seed: int, angles) -> dict:
    """The posterior columns of a panel's row (see `fit_panel`)."""
    from ._measured_inputs import KnownInputs, posterior_predictive_check
    from ._posterior import sample_posterior

    inputs = KnownInputs(known) if known else None
    steps = int(settings["max_steps"])
    pr = sample_posterior(fwd, L, free=tuple(names) + ("discrepancy",), angles=have, instrument_sd=sd, inputs=inputs,
                          walkers=int(settings["walkers"]), max_steps=steps, min_steps=min(500, steps), check_every=min(250, steps),
                          min_ess=float(settings["min_ess"]), max_rhat=float(settings.get("max_rhat", MAX_RHAT)), init=fr, seed=seed, progress=False)
    check = posterior_predictive_check(pr, fwd, L, angles=have, instrument_sd=sd, seed=seed)
    out = {"posterior_converged": bool(pr.converged), "steps": int(pr.steps), "rhat_max": max(pr.rhat.values()),
           "ess_bulk_min": min(pr.ess_bulk.values()), "predictive_p": float(check["p_value"]),
           "predictive_p_se": float(check["p_value_se"]), "posterior_edge": ";".join(f"{n}:{side}" for n, side in pr.at_edge.items())}
    for name in list(pr.names) + (["mean_tilt"] if "mean_tilt" in pr.q50 else []):
        out[f"{name}_q05"], out[f"{name}_q50"], out[f"{name}_q95"] = pr.q05[name], pr.q50[name], pr.q95[name]
    for j, a in enumerate(angles):
        out[f"L{a}_q05"], out[f"L{a}_q95"] = float(check["L_star_q05"][j]), float(check["L_star_q95"][j])
    if inputs is not None:
        for name, v in inputs.shift_table({n: pr.draws(n) for n in pr.names}).items():
            out[f"{name}_known_z"] = v["z"]
    return out


def _columns(rows: list[dict]) -> list[str]:
    """The union of the rows' columns, in the order they first appear."""
    columns: list[str] = []
    for r in rows:
        columns += [k for k in r if k not in columns]
    return columns


def _write_table(path: Path, rows: list[dict]) -> None:
    """All rows (union of their columns) to CSV, written atomically (`atomic_path`)."""
    columns = _columns(rows)
    with atomic_path(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=columns)
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k, "")) for k in columns})


def _write_netcdf(path: Path, rows: list[dict]) -> None:
    """The rows as an xarray Dataset over a `panel` dimension (numbers as float, NaN where absent;
    text as strings), written atomically as NetCDF (h5netcdf)."""
    import xarray as xr

    data = {}
    for c in [c for c in _columns(rows) if c != "id"]:
        values = [r.get(c) for r in rows]
        numbers = [_as_number(v) for v in values]  # rows resumed from the CSV hold their numbers as text
        if c not in TEXT_COLUMNS and all(x is not None for x in numbers):
            data[c] = ("panel", np.array(numbers, dtype=float))
        else:
            data[c] = ("panel", np.array(["" if v is None else str(v) for v in values], dtype=object))
    ds = xr.Dataset(data, coords={"panel": np.array([str(r["id"]) for r in rows], dtype=object)},
                    attrs={"source": "paintjax fit --data", "angles_deg": list(PANEL_ANGLES)})
    with atomic_path(path) as tmp:
        ds.to_netcdf(str(tmp), engine="h5netcdf")


def _as_number(v) -> float | None:
    """A table cell as a float (NaN when empty, 1/0 for booleans), or None when it is text."""
    if v is None or v == "":
        return float("nan")
    if isinstance(v, str):
        if v in ("True", "False"):
            return float(v == "True")
        try:
            return float(v)
        except ValueError:
            return None
    return float(v)


def figure_name(panel_id: str) -> str:
    """File name of a panel's figure: the id with characters other than letters, digits, '.', '_' and
    '-' replaced by '_', plus a short hash of the id when that changed it (distinct ids, distinct files)."""
    safe = "".join(ch if ch.isascii() and (ch.isalnum() or ch in "._-") else "_" for ch in panel_id).lstrip(".") or "_"
    if safe != panel_id:
        safe += "-" + hashlib.sha256(panel_id.encode()).hexdigest()[:8]
    return safe + ".png"


def panel_figure(panel: dict, row: dict, path) -> None:
    """Measured L* (with ±2 SD bars) against the least-squares curve and, with a posterior, its 90 %
    posterior-predictive band, per aspecular angle; written atomically as PNG (`predictive_plot`)."""
    import matplotlib

    matplotlib.use("Agg")  # a Dask worker has no display
    import matplotlib.pyplot as plt

    from ._posterior_output import predictive_plot

    fitted = [x for x in PANEL_ANGLES if row.get(f"L{x}_fit") not in (None, "")]  # the angles of the panel's model
    band = None
    if f"L{fitted[0]}_q05" in row:
        band = ([float(row[f"L{x}_q05"]) for x in fitted], [float(row[f"L{x}_q95"]) for x in fitted])
    fig = predictive_plot(PANEL_ANGLES, panel["L_star"], measured_sd=panel["sd"], model_angles=fitted,
                          fit=[float(row[f"L{x}_fit"]) for x in fitted], band=band, path=path,
                          title=f"{row['id']}: χ² {float(row['chi2']):.3g} for {int(row['dof'])} dof")
    plt.close(fig)


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
    posterior: dict | None = None,
    figures: bool = True,
    scheduler: str | None = None,
    workers: int = 2,
    client=None,
    on_result: Callable[[dict, int, int], None] | None = None,
) -> list[dict]:
    """Fit every panel of a CSV file, one Dask task per panel, into a results table that resumes.

    Arguments:
        data: the panels' CSV file (`read_panels`).
        out: the results CSV; the same table goes to NetCDF beside it (`.nc`) and the figures to a
            `figures/` folder beside it. Rows already there with the same settings are kept and not recomputed.
        forward, free, n_starts, seed: the fit (`fit_least_squares` through `make_forward`).
        posterior: None, or the posterior settings {"walkers", "max_steps", "min_ess"} (`fit_panel`).
        figures: write a figure per panel (`panel_figure`).
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
    if posterior is not None:
        check_walkers(int(posterior["walkers"]), len(free) + 1)
        if int(posterior["max_steps"]) < 1 or not float(posterior["min_ess"]) >= 0 or not float(posterior.get("max_rhat", MAX_RHAT)) >= 1:
            raise ValueError(f"posterior max_steps must be >= 1, min_ess >= 0 and max_rhat >= 1, got {posterior}")
    panels, bad = read_panels(data)
    stray = sorted({n for p in panels for n in p["known"]} - set(free))
    if stray:
        raise ValueError(f"data columns {stray} are known inputs of parameters that are not free in this fit (free: {', '.join(free)})")
    check_angles(panels, forward)
    key = settings_key(forward, free, n_starts, seed, posterior)
    done = {r["id"]: r for r in read_results(out) if r.get("status") == "ok" and r.get("settings") == key}
    results = {p["id"]: done[p["id"]] for p in panels if p["id"] in done}
    todo = [p for p in panels if p["id"] not in done]
    out.parent.mkdir(parents=True, exist_ok=True)
    figure_dir = out.parent / "figures"

    def table():  # the panels in file order (those finished so far), then the bad rows
        return [results[p["id"]] for p in panels if p["id"] in results] + bad

    def write():
        rows = table()
        _write_table(out, rows)
        _write_netcdf(out.with_suffix(".nc"), rows)

    write()
    if todo:
        own = client is None
        address = scheduler or os.environ.get("DASK_SCHEDULER_ADDRESS")
        if own:
            client = Client(address) if address else Client(LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True,
                                                                            dashboard_address=":0"))
        try:
            futures = {client.submit(fit_panel, p, forward, tuple(free), int(n_starts), int(seed), posterior, key=f"fit-{key}-{p['id']}",
                                     pure=False): p for p in todo}
            for n, fut in enumerate(as_completed(futures), start=1):
                p = futures[fut]
                try:
                    row = fut.result()
                except Exception as err:  # a panel whose fit fails is a row with its error, not the end of the batch
                    row = {"id": p["id"], "status": "error", "error": f"{type(err).__name__}: {err}"}
                results[p["id"]] = row
                if figures and row["status"] == "ok":
                    figure_dir.mkdir(parents=True, exist_ok=True)
                    panel_figure(p, row, figure_dir / figure_name(p["id"]))
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
