"""Named forward models (the CLI's `--forward`): `make_forward`, `register_forward` and the built-in factories."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

from ..instrument._geometry import ASPECULAR_45, STANDARD_ASPECULAR, ma98_geometry
from ..instrument._hot_spot import HotSpot
from ._analytic import AnalyticForward
from ._emulator import build_emulator
from ._forward import ForwardModel


# ------------------------------------------------------------------------------------------
# Registry of named forward models (the CLI's --forward)
# ------------------------------------------------------------------------------------------
def _geometry(angles):
    """MA98 in-plane geometry of 45° illumination at these aspecular angles (the analytic models compute any)."""
    return ma98_geometry(45.0, STANDARD_ASPECULAR if angles is None else angles)


def _analytic(free, fixed, bounds, angles=None, **kw):
    return AnalyticForward(_geometry(angles))


def _analytic_kirchhoff(free, fixed, bounds, angles=None, **kw):
    return AnalyticForward(_geometry(angles), lobe="kirchhoff")


def _analytic_hot_spot(free, fixed, bounds, angles=None, **kw):
    from .._samples import load_sample

    # both reference samples share this layer
    return AnalyticForward(_geometry(angles), hot_spot=HotSpot.for_sample(load_sample("silver1")))


def _analytic_mirror(free, fixed, bounds, angles=None, **kw):
    return AnalyticForward(_geometry(angles), rough=False)


def _analytic_emulator(free, fixed, bounds, *, cache_dir="default", n_train: int = 256, n_test: int = 64, seed: int = 0,
                       progress: bool = False, angles=None, **kw):
    from ._parameters import make_spec

    base = AnalyticForward(_geometry(angles))
    names = tuple(n for n in free if n != "discrepancy")
    spec = make_spec(names, {k: v for k, v in (bounds or {}).items() if k in names})
    restricted = base.restrict(names, {k: v for k, v in (fixed or {}).items() if k != "discrepancy"})
    return build_emulator(restricted, spec, n_train=n_train, n_test=n_test, seed=seed, cache_dir=cache_dir, progress=progress)


#: name → (factory(free, fixed, bounds, **options) → ForwardModel, one-line description).
#: The tracer registers e.g. "tracer-emulator" with `register_forward`.
FORWARDS: dict[str, tuple[Callable, str]] = {
    "analytic": (_analytic, "analytic single scatter, rough platelets (Beckmann limit of the Kirchhoff BRDF)"),
    "analytic-kirchhoff": (_analytic_kirchhoff, "analytic single scatter, full Kirchhoff series lobe (slower)"),
    "analytic-hot-spot": (_analytic_hot_spot, "'analytic' with the entry and exit paths correlated over the reference samples' "
                          "platelet widths (D50 16 µm, t 1 µm, PVC 0.2; closer to the tracer's single scattering)"),
    "analytic-mirror": (_analytic_mirror, "analytic single scatter, mirror platelets (σ, τ not used)"),
    "analytic-emulator": (_analytic_emulator, "Gaussian-process emulator of 'analytic' (tests the emulator path the tracer will use)"),
}
#: name → the aspecular angles (45° illumination) the model can give; the analytic models compute any
#: in-plane angle, and list MA98's six.
ANGLES: dict[str, tuple[float, ...]] = {name: ASPECULAR_45 for name in FORWARDS}


def register_forward(name: str, factory: Callable, description: str, angles=STANDARD_ASPECULAR) -> None:
    """Make a forward model available by name (CLI ``--forward``, `make_forward`).

    Arguments:
        name: the name.
        factory: ``factory(free, fixed, bounds, **options) -> ForwardModel``; for the tracer,
            typically `build_emulator` over a `CallableForward` with a fixed key. Where `angles` lists more
            than the standard five it must take an ``angles=`` option (the outputs it returns; default the five).
        description: one line for ``--help``.
        angles: the aspecular angles it can give.
    """
    if not name or not callable(factory):
        raise ValueError("register_forward needs a non-empty name and a callable factory")
    FORWARDS[name] = (factory, description)
    ANGLES[name] = tuple(float(a) for a in angles)


def forward_angles(name: str) -> tuple[float, ...]:
    """The aspecular angles the registered forward model `name` can give (without building it)."""
    if name not in FORWARDS:
        raise ValueError(f"unknown forward model {name!r}; known: {', '.join(FORWARDS)}")
    return ANGLES.get(name, STANDARD_ASPECULAR)


def make_forward(name: str, free: Sequence[str] = (), fixed: Mapping[str, float] | None = None,
                 bounds: Mapping[str, tuple[float, float]] | None = None, *, angles=None, **options) -> ForwardModel:
    """Build the registered forward model `name` for the given free/fixed parameters, at `angles`
    (aspecular, 45° illumination; default the standard five; ValueError naming the model and the angle
    where it does not give one)."""
    covered = forward_angles(name)
    if angles is None:
        return FORWARDS[name][0](tuple(free), dict(fixed or {}), dict(bounds or {}), **options)
    angles = tuple(float(a) for a in angles)
    missing = [a for a in angles if a not in covered]
    if missing:
        raise ValueError(f"forward model {name!r} gives L* at {', '.join(f'{a:g}' for a in covered)}°, not at "
                         f"{', '.join(f'{a:g}' for a in missing)}°")
    model = FORWARDS[name][0](tuple(free), dict(fixed or {}), dict(bounds or {}), angles=angles, **options)
    if tuple(float(a) for a in model.aspecular_deg) != angles:
        raise ValueError(f"forward model {name!r} returned L* at {list(model.aspecular_deg)}°, not at the {list(angles)}° asked")
    return model
