"""Experiment: how large is the Monte Carlo error of a calibration study's posteriors?

A calibration study (`experiments/coverage.py`) counts, per synthetic panel, whether the truth lies inside the
posterior's central intervals. Those intervals come from one emcee ensemble per panel, stopped by the package's
rule (R-hat over the walkers, emcee's τ, ESS ≥ 1000). If the ensemble has not explored the posterior as the rule
says, its intervals move from one run to the next, and an interval that moves about at random covers the truth
less often than its level: Monte Carlo error alone makes central intervals under-cover.

This reruns the posterior of some of a study's panels `--repeats` times, each an independent ensemble (another
seed for its least-squares starts and for its walkers, the same data, number of starts and stopping rule as the
study), and reports per parameter:

* the spread (SD over the repeats and the study's own run, pooled over the panels) of the PIT, the posterior CDF at
  the truth, against the spread an ESS of `n_eff` independent draws would give (√(PIT (1 − PIT) / n_eff));
* how often the repeats and the study's run disagree on whether the truth is inside the central 68 % interval;
* the spread of the posterior median in units of the posterior SD.

With `--walkers`, `--start` or `--moves` other than the study's, the same panels under another sampler; the study's
own run then does not count among the runs compared.

With `--against OTHER_STUDY` no posterior runs: the study's posteriors are compared panel by panel with another study's
of the same panels (the same seed, so the same truths and data; another sampler): how far the PIT moves, and how many
truths the change brings into or out of the central intervals. Writes <study>/compared_with_<other>.json.

Writes <study>/reproducibility_w<walkers>_<start>_<moves>.json (atomic; rewritten as each posterior finishes, the summary
at the end).

Run: python experiments/posterior_reproducibility.py --study experiments/output/coverage_tracer_wide_seed2032
         [--panels 0-9] [--repeats 3] [--walkers 16] [--start dispersed|ball] [--moves stretch|de] [--workers 2]
     python experiments/posterior_reproducibility.py --study A --against B
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import sys
import time
from pathlib import Path

import numpy as np
from coverage import SAMPLER, SAMPLER_BEFORE, fit_and_sample, sampler_settings  # the study's own fit and posterior of one dataset
from error_law_check import NAMES, load_study  # the parameters and the study folder's check, shared with that experiment

SEED_STRIDE = 10007  # repeat k of panel i: least-squares starts and walkers seeded study_seed + i + SEED_STRIDE · (k + 1)


def one_posterior(task: dict) -> dict:
    """The least-squares fit and one posterior of one panel (a task), as the study made them, with the task's seed
    (the fit's random starts too: where on a flat ridge of good fits the walkers start is part of what varies)."""
    y, truth = np.asarray(task["L_star"]), task["truth"]
    t0 = time.perf_counter()
    fr, post = fit_and_sample("tracer-emulator-wide", {}, y, NAMES, {}, task["starts"], task["steps"], task["walkers"], task["seed"],
                              task["converge"], task["sampler"])
    out = {"i": task["i"], "repeat": task["repeat"], "seed": task["seed"], "start": fr.values, "start_chi2": fr.chi2,
           "steps": post.steps, "n_eff": post.n_eff,
           "converged": post.converged, "rhat_max": max(post.rhat.values()), "seconds": time.perf_counter() - t0}
    for n in NAMES:
        d = post.draws(n)
        lo, hi = post.interval(n, 0.68)
        out[n] = {"pit": float(np.mean(d < truth[n])), "median": float(np.median(d)), "sd": float(np.std(d)),
                  "inside68": bool(lo <= truth[n] <= hi)}
    print(f"panel {task['i']} repeat {task['repeat']}: " + " ".join(f"{n} PIT {out[n]['pit']:.3f}" for n in NAMES)
          + f", {post.steps} steps, n_eff {post.n_eff:.0f} ({out['seconds']:.0f} s)", flush=True)
    return out


def summarise(runs: list[dict], rows: list[dict], panels: list[int], with_study: bool = True) -> dict:
    """Per parameter: the PIT's spread over the repeats (and the study's run, `with_study`: when it used the same sampler)
    against the spread n_eff independent draws give, the panels whose runs disagree on the 68 % interval, the median's
    spread in posterior SDs."""
    out = {}
    for n in NAMES:
        sd_pit, sd_ideal, sd_median, disagree = [], [], [], 0
        for i in panels:
            mine = [r for r in runs if r["i"] == i]
            # the study's own run is one more independent posterior of the panel (its seed differs from the repeats')
            study = [rows[i]] if with_study else []
            pit = np.array([r[n]["pit"] for r in mine] + [r["pit"][n] for r in study])
            n_eff = np.array([r["n_eff"] for r in mine] + [r["n_eff"] for r in study])
            sd_pit.append(np.std(pit, ddof=1))
            sd_ideal.append(np.sqrt(np.mean(pit * (1 - pit) / n_eff)))
            sd_median.append(np.std([r[n]["median"] for r in mine], ddof=1) / np.mean([r[n]["sd"] for r in mine]))
            inside = {r[n]["inside68"] for r in mine} | {bool(r["inside"][f"{n}@0.68"]) for r in study}
            disagree += len(inside) > 1
        out[n] = {"pit_sd_over_repeats": float(np.sqrt(np.mean(np.square(sd_pit)))),
                  "pit_sd_from_n_eff": float(np.sqrt(np.mean(np.square(sd_ideal)))),
                  "median_sd_in_posterior_sd": float(np.sqrt(np.mean(np.square(sd_median)))),
                  "panels_disagreeing_on_68": disagree}
    return out


def compare_studies(rows: list[dict], other: list[dict]) -> dict:
    """Per parameter, the same panels' posteriors in two studies: RMS and largest PIT change, and per level the truths
    inside in both, in `rows` only (gained) and in `other` only (lost)."""
    for r, o in zip(rows, other):
        if not np.allclose(r["L_star"], o["L_star"]) or r["truth"] != o["truth"]:
            raise SystemExit("the two studies do not hold the same panels (truths and L* differ): give studies of the same seed")
    out = {}
    for n in NAMES:
        d = np.array([r["pit"][n] - o["pit"][n] for r, o in zip(rows, other)])
        out[n] = {"pit_change_rms": float(np.sqrt(np.mean(d**2))), "pit_change_max": float(np.max(np.abs(d))),
                  "largest_at_panel": int(np.argmax(np.abs(d)))}
        for lv in sorted({k.split("@")[1] for k in rows[0]["inside"] if k.startswith(n + "@") and k.count("@") == 1}):
            a = np.array([r["inside"][f"{n}@{lv}"] for r in rows], bool)
            b = np.array([o["inside"][f"{n}@{lv}"] for o in other], bool)
            out[n][f"inside@{lv}"] = {"both": int(np.sum(a & b)), "gained": int(np.sum(a & ~b)), "lost": int(np.sum(~a & b)),
                                       "this": int(a.sum()), "other": int(b.sum())}
    return out


def parse_panels(text: str, count: int) -> list[int]:
    """'0-9' or '0,3,7' → panel indices, each in [0, count)."""
    out = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b) + 1)) if b else [int(a)]
    bad = [i for i in out if not 0 <= i < count]
    if bad or not out:
        raise SystemExit(f"--panels must name panels in [0, {count - 1}], got {text!r}")
    return sorted(set(out))


def main(argv=None) -> int:
    from paintjax import atomic_write_json

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--study", required=True, help="a finished tracer-emulator-wide study folder (its summary.json)")
    ap.add_argument("--panels", default="0-9", help="panel indices: '0-9' or '0,3,7'")
    ap.add_argument("--repeats", type=int, default=3, help="independent posteriors per panel (≥ 2)")
    ap.add_argument("--walkers", type=int, default=None, help="ensemble size (default: the study's)")
    ap.add_argument("--workers", type=int, default=2, help="processes running posteriors side by side")
    ap.add_argument("--against", help="another study of the same panels: compare the two, panel by panel (runs no posterior)")
    ap.add_argument("--start", default=SAMPLER["start"], choices=("dispersed", "ball"), help="where the walkers start (default dispersed)")
    ap.add_argument("--moves", default=SAMPLER["moves"], choices=("stretch", "de"), help="emcee's proposal (default stretch)")
    a = ap.parse_args(argv)
    study = Path(a.study)
    summary = load_study(study)
    if a.repeats < 2:
        raise SystemExit(f"--repeats must be at least 2, got {a.repeats}")
    if not 1 <= a.workers <= 16:
        raise SystemExit(f"--workers must be in [1, 16], got {a.workers}")
    rows = summary["rows"]
    if a.against:
        other = load_study(Path(a.against))
        if len(other["rows"]) != len(rows):
            raise SystemExit(f"--against {a.against}: {len(other['rows'])} panels, the study {len(rows)}")
        table = compare_studies(rows, other["rows"])
        atomic_write_json(study / f"compared_with_{Path(a.against).name}.json", {"study": study.name, "sampler": summary.get("sampler", SAMPLER_BEFORE),
              "against": Path(a.against).name, "against_sampler": other.get("sampler", SAMPLER_BEFORE), "panels": len(rows), "summary": table})
        print(f"{study.name} against {Path(a.against).name}, {len(rows)} panels (inside: this study / the other; gained, lost):")
        for n, v in table.items():
            cells = "; ".join(f"@{k.split('@')[1]} {c['this']}/{c['other']} (+{c['gained']} −{c['lost']})" for k, c in v.items() if k.startswith("inside@"))
            print(f"{n:6s} PIT change RMS {v['pit_change_rms']:.3f}, largest {v['pit_change_max']:.3f} (panel {v['largest_at_panel']}); {cells}")
        return 0
    panels = parse_panels(a.panels, len(rows))
    walkers = int(a.walkers or summary["walkers"])
    sampler = sampler_settings({"start": a.start, "moves": a.moves})
    # the study's own posterior is one more independent run only if it was made with the same sampler
    with_study = walkers == summary["walkers"] and sampler == summary.get("sampler", SAMPLER_BEFORE)
    tasks = [{"i": i, "repeat": k, "L_star": rows[i]["L_star"], "truth": rows[i]["truth"], "starts": summary["lsq_starts"],
              "seed": summary["seed"] + i + SEED_STRIDE * (k + 1), "walkers": walkers,
              "steps": summary["steps"], "converge": summary["converge"], "sampler": sampler} for i in panels for k in range(a.repeats)]
    t0 = time.perf_counter()
    path = study / f"reproducibility_w{walkers}_{sampler['start']}_{sampler['moves']}.json"
    head = {"study": study.name, "panels": panels, "repeats": a.repeats, "walkers": walkers, "study_walkers": summary["walkers"],
            "sampler": sampler, "study_sampler": summary.get("sampler", SAMPLER_BEFORE), "study_run_counted": with_study,
            "steps": summary["steps"], "study_pit": {str(i): rows[i]["pit"] for i in panels}}
    runs = []
    with mp.get_context("spawn").Pool(a.workers) as pool:
        for run in pool.imap_unordered(one_posterior, tasks):
            runs.append(run)  # the runs so far, after each one (an interrupted experiment keeps them)
            atomic_write_json(path, head | {"done": len(runs), "of": len(tasks), "seconds": time.perf_counter() - t0, "runs": runs})
    runs.sort(key=lambda r: (r["i"], r["repeat"]))
    table = summarise(runs, rows, panels, with_study)
    out = head | {"done": len(runs), "of": len(tasks), "seconds": time.perf_counter() - t0, "summary": table, "runs": runs}
    atomic_write_json(path, out)
    print(f"{len(panels)} panels × {a.repeats} independent posteriors, {walkers} walkers, start {sampler['start']}, moves "
          f"{sampler['moves']}{' and the study' + chr(39) + 's own' if with_study else ''} ({out['seconds']:.0f} s):")
    print(f"{'':6s} {'PIT SD (repeats)':>17s} {'PIT SD (n_eff)':>15s} {'median SD / post. SD':>21s} {'disagree @68':>13s}")
    for n, v in table.items():
        print(f"{n:6s} {v['pit_sd_over_repeats']:17.3f} {v['pit_sd_from_n_eff']:15.3f} {v['median_sd_in_posterior_sd']:21.2f} "
              f"{v['panels_disagreeing_on_68']:>6d} / {len(panels)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
