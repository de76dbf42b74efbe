"""Settings of a tracer run (`TracerOptions`), its energy ledger's keys and the energy-creation refusal."""

from __future__ import annotations

import math
from fractions import Fraction

import equinox as eqx

#: Keys of the energy ledger, in order.
LEDGER_KEYS = ("top_reflection", "exited", "absorbed_platelets", "absorbed_primer", "roulette", "caps")
_BIG = 1e30
_MAX_GROWTH = 4.0  # adaptive rounds grow the rays at most this factor

#: Largest net energy (fraction of the incident flux) the platelets may create, i.e. negative
#: platelet absorption in the ledger, before `trace` refuses the result (`EnergyCreationError`).
MAX_CREATED_ENERGY = 0.01


#: Rays in flight per device by default: a GPU needs a wide wavefront (on an H200, 16 384 lanes reached
#: L* SE 0.3 at five angles in a median 0.94 s against 3.10 s with 2 048, and 65 536 were slower again:
#: BENCHMARKS.md); on a CPU 2 048 keep the state in cache.
DEFAULT_LANES = {"cpu": 2048, "gpu": 16384}


def default_lanes() -> int:
    """`DEFAULT_LANES` for JAX's default backend (GPU or TPU: the "gpu" entry)."""
    import jax

    return DEFAULT_LANES["cpu" if jax.default_backend() == "cpu" else "gpu"]


class EnergyCreationError(ValueError):
    """The platelet BRDF returned more light than it received (its albedo exceeds 1 somewhere)."""


class TracerOptions(eqx.Module):
    """Performance and estimator settings of `trace` (all static).

    Arguments:
        lanes: rays in flight per device (default `default_lanes()`: 16 384 on a GPU, 2 048 on a CPU).
        steps_per_call: steps per jit call (a step = one event or `cells_per_step` cells).
        cells_per_step: grid cells a ray may cross per step (≥ 2).
        shadow_leg_cells: grid cells a shadow ray crosses per pass (≥ 2: a resumed leg may start in the
            cell where the last one stopped): the step's shadow rays are
            traced in passes over a compacted buffer, and one not yet decided resumes where it stopped
            in the next pass, until every shadow ray is decided within the step (the answer does not
            depend on it). Short legs stop paying for cells a ray never reaches: the fixed-length walk
            costs the cells to the top of the basecoat at the flat coat's critical angle
            (`_shadow_cell_bound`) for every ray, most of which end sooner, blocked or out.
        batches: groups of lanes for the batch-means standard errors (≥ 8).
        roulette_weight: Russian roulette below this weight (0 disables roulette).
        max_steps: steps after which a ray is capped (its weight goes to the ledger's caps).
        randomize_azimuth: rotate the instrument by a random azimuth per ray.
        shadow_roulette: NEE contributions (reflectance-factor units per ray) below this are kept
            with probability value/threshold and raised to it (unbiased; 0 disables).
        shadow_buffer: shadow rays traced per pass, as a fraction of lanes × detectors; active
            shadow rays are compacted into this buffer (more passes run when it overflows).
        edges: "scatter" (default): a ray entering a platelet through a side face is scattered by
            the platelet BRDF about that face's normal (aluminium side walls); "absorb": side
            faces absorb (dark, broken edges; also the thin-platelet limit of the analytic model).
        mis: with finite detector apertures and a flat coat, combine NEE with the BRDF-sampled
            exits into each aperture by multiple importance sampling (balance heuristic);
            False: NEE alone (the histogram is always reported on its own as well).
        reverse_share: bidirectional MIS where both ends are delta directions (collimated beam,
            point detectors, flat coat, BRDF without a delta part): per detector a reverse pass
            (reciprocity: the detector is the source, the source the only detector) traces this
            many rays per forward ray, and the NEE of both passes is weighted by the balance
            heuristic over their path densities. 0: the forward tracer alone; a number: the same
            share for every detector; a tuple: one per detector (0: none for it; positive shares
            are rounded to ratios of small integers, `detector_reverse_shares`); "aspecular"
            (default): by each detector's aspecular angle, `REVERSE_SHARE_BY_ASPECULAR` — none
            near specular, where the light is mostly the beam scattered once, which forward NEE
            finds, and more the farther out, where multiply scattered light reaches the detector
            through narrow lobes that the reverse pass samples. Any shares estimate the same
            expectation; they change the variance only. It relies on
            reciprocity: of the platelet BRDF (all of paintjax's are) and of the scene, which
            overlapping boxes break (a ray starting inside a box passes through it, one arriving
            from outside does not), so arrays should be overlap-free (`array_statistics`).
        float64: trace in float64 when x64 is enabled (default float32 geometry and platelet BRDF
            evaluations, which are ample for µm-scale boxes in a sub-mm tile and twice as fast;
            tallies are float64 under x64).

    `batches`, `float64`, `mis` and `reverse_share` are read on the host only (scene flags, dtypes,
    summaries): the compiled kernel is cached without them (`_kernel_options`), so it must not read them.
    """

    lanes: int = eqx.field(static=True, default_factory=lambda: default_lanes())
    steps_per_call: int = eqx.field(static=True, default=16)
    cells_per_step: int = eqx.field(static=True, default=3)
    batches: int = eqx.field(static=True, default=32)
    roulette_weight: float = eqx.field(static=True, default=0.05)
    max_steps: int = eqx.field(static=True, default=1000)
    randomize_azimuth: bool = eqx.field(static=True, default=True)
    float64: bool = eqx.field(static=True, default=False)
    shadow_roulette: float = eqx.field(static=True, default=0.02)
    shadow_buffer: float = eqx.field(static=True, default=0.25)
    shadow_leg_cells: int = eqx.field(static=True, default=4)
    edges: str = eqx.field(static=True, default="scatter")
    mis: bool = eqx.field(static=True, default=True)
    reverse_share: float | tuple[float, ...] | str = eqx.field(static=True, default="aspecular")

    def __check_init__(self):
        for name, v, lo in (("lanes", self.lanes, 1), ("steps_per_call", self.steps_per_call, 1),
                            ("cells_per_step", self.cells_per_step, 2), ("shadow_leg_cells", self.shadow_leg_cells, 2), ("batches", self.batches, 8),
                            ("max_steps", self.max_steps, 1)):
            if int(v) < lo:
                raise ValueError(f"{name} must be an integer >= {lo}, got {v!r}")
        if self.lanes % self.batches:
            raise ValueError(f"lanes ({self.lanes}) must be a multiple of batches ({self.batches})")
        if not (0.0 <= self.shadow_roulette < 10.0):
            raise ValueError(f"shadow_roulette must lie in [0, 10), got {self.shadow_roulette!r}")
        if not (0.0 < self.shadow_buffer <= 1.0):
            raise ValueError(f"shadow_buffer must lie in (0, 1], got {self.shadow_buffer!r}")
        if self.edges not in ("scatter", "absorb"):
            raise ValueError(f"edges must be 'scatter' or 'absorb', got {self.edges!r}")
        shares = self.reverse_share if isinstance(self.reverse_share, tuple) else (self.reverse_share,)
        try:
            ok = self.reverse_share == "aspecular" or (len(shares) > 0 and all(0.0 <= float(v) <= 16.0 for v in shares))
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise ValueError(f"reverse_share must be 'aspecular', a number in [0, 16] or a tuple of them (one per detector), "
                             f"got {self.reverse_share!r}")
        if not (0.0 <= self.roulette_weight < 1.0):
            raise ValueError(f"roulette_weight must lie in [0, 1), got {self.roulette_weight!r}")


#: Longest cycle of sources the reverse pool deals its rays over (`detector_reverse_shares`).
MAX_SOURCE_WHEEL = 64


#: `TracerOptions.reverse_share = "aspecular"`: (|aspecular angle| from which [deg], reverse rays per forward ray)
#: in increasing order; none below the first, `OUT_OF_PLANE_REVERSE_SHARE` for detectors outside the illumination
#: plane. Chosen on Silver #1's five MA98 angles: with (0, 0, 0, 0.5, 1) the time to L* SE ≤ 0.3 at all five
#: fell 1.7× against 0.5 for every detector (BENCHMARKS.md); the variance, not the expectation, depends on it.
REVERSE_SHARE_BY_ASPECULAR = ((60.0, 0.5), (90.0, 1.0))
OUT_OF_PLANE_REVERSE_SHARE = 0.5


def detector_reverse_shares(reverse_share, m: int, aspecular_deg=None):
    """Reverse rays per forward ray for each of `m` detectors, and the cycle of detector indices the
    reverse pool deals its rays over (ray r comes from detector wheel[r mod len(wheel)]).

    A number applies to every detector; a tuple must have one entry per detector; "aspecular" follows
    `REVERSE_SHARE_BY_ASPECULAR` at the detectors' aspecular angles `aspecular_deg` (m,) [deg]. Positive
    shares are rounded to ratios of small integers (relative to the largest, fractions of denominators up to
    `MAX_SOURCE_WHEEL`, the wheel at most that long unless there are more detectors) and the returned shares
    are the rounded ones, which the MIS weights of both passes use; equal shares give
    the wheel 0, 1, …, m − 1.
    """
    import numpy as np

    if isinstance(reverse_share, str):
        gamma = np.abs(np.asarray(aspecular_deg, dtype=float)).reshape(-1)
        if reverse_share != "aspecular" or gamma.shape != (m,):
            raise ValueError(f"reverse_share 'aspecular' needs the {m} detectors' aspecular angles, got {reverse_share!r}, {aspecular_deg!r}")
        reverse_share = np.where(np.isnan(gamma), OUT_OF_PLANE_REVERSE_SHARE, 0.0)
        for start, share in REVERSE_SHARE_BY_ASPECULAR:
            reverse_share = np.where(gamma >= start, share, reverse_share)
    s = np.asarray(reverse_share, dtype=float)
    if s.ndim == 0:
        s = np.full(m, float(s))
    if s.shape != (m,):
        raise ValueError(f"reverse_share must be a number or a tuple of {m} numbers (one per detector), got {reverse_share!r}")
    on = np.flatnonzero(s > 0)
    if on.size == 0:
        return np.zeros(m), np.zeros(1, np.int64)
    total = float(s[on].sum())
    # each share relative to the largest as a fraction of a small denominator, the wheel their common multiple
    for denominator in range(MAX_SOURCE_WHEEL, 0, -1):
        ratios = [Fraction(float(v)).limit_denominator(denominator) for v in s[on] / s[on].max()]
        common = math.lcm(*(r.denominator for r in ratios))
        if common > MAX_SOURCE_WHEEL:
            continue
        k = np.array([max(1, int(r * common)) for r in ratios], dtype=np.int64)
        if k.sum() <= MAX_SOURCE_WHEEL:
            break
    k = k // np.gcd.reduce(k)
    out = np.zeros(m)
    out[on] = total * k / k.sum()
    return out, np.repeat(on, k)
