"""Build (or load) the registered tracer emulator and record its build time and errors, next to
a plain GP fitted to the same design (no analytic mean) for comparison.

Writes experiments/output/tracer_forward/emulator.json (atomic). The emulator is cached under
`$PAINTJAX_CACHE/emulators` (content-hashed key; design evaluations check-pointed, so an
interrupted build resumes).

Run: python experiments/build_tracer_emulator.py
"""

from __future__ import annotations

import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from paintjax import (
    atomic_write_json,  # noqa: E402
    enable_compilation_cache,  # noqa: E402
)
from paintjax.inverse import (  # noqa: E402
    TRACER_BOX,
    TRACER_PARAMETERS,
    Emulator,
    direct_tracer,
    fit_emulator,
    make_forward,  # noqa: E402
    tracer_info,
)

OUT = Path(__file__).parent / "output" / "tracer_forward"


def main():
    enable_compilation_cache()
    t0 = time.perf_counter()
    em = make_forward("tracer-emulator", TRACER_PARAMETERS, progress=True)
    wall = time.perf_counter() - t0
    info = tracer_info(em)
    fn = direct_tracer(em)
    rec = {"box": TRACER_BOX, "settings": fn.settings.__dict__, "wall_seconds_this_process": wall,
           "tracer_evaluations_this_process": fn.evaluations, "tracer_seconds_this_process": fn.seconds,
           "error_sd": np.asarray(em.error_sd).tolist(), "key": em.key} | info
    import numpy as _np

    from paintjax import default_cache_dir

    path = default_cache_dir() / "emulators" / f"emulator-{em.key}.npz"
    with _np.load(path) as d:
        rec["design_seconds"] = float(d["design_seconds"])
        rec["gp_train_seconds"] = float(d["train_seconds"])
        rec["held_out_rms_crn"] = d["held_out_rms"].tolist()
        rec["loo_rms_crn"] = d["loo_rms"].tolist()
        rec["cv_rms_crn"] = np.asarray(Emulator.error_sd.fget(em)).tolist()  # pooled, before the spread
        Yt = d["Yt"]
        rec["held_out_L_range"] = [Yt.min(0).tolist(), Yt.max(0).tolist()]
        # the same design fitted by a plain GP over θ (no analytic mean), for comparison
        plain = fit_emulator(d["Z"], d["Y"], d["Zt"], d["Yt"], em.spec, None, (), em.angles, em.source, em.key)
        rec["plain_gp"] = {"held_out_rms_crn": plain["held_out_rms"].tolist(), "loo_rms_crn": plain["loo_rms"].tolist()}
    atomic_write_json(OUT / "emulator.json", rec)
    print({k: rec[k] for k in ("design_seconds", "gp_train_seconds", "held_out_rms_crn", "loo_rms_crn", "cv_rms_crn", "plain_gp", "seed_spread_sd", "error_sd")})


if __name__ == "__main__":
    main()
