"""Named forward models (the CLI's `--forward`): `make_forward`, `register_forward` and the built-in factories."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

from ..instrument._hot_spot import HotSpot
from ._analytic import AnalyticForward
from ._emulator import build_emulator
from ._forward import ForwardModel


# ------------------------------------------------------------------------------------------
# Registry of named forward models (the CLI's --forward)
# ------------------------------------------------------------------------------------------
def _analytic(free, fixed, bounds, **kw):
    return AnalyticForward()


def _analytic_kirchhoff(free, fixed, bounds, **kw):
    return AnalyticForward(lobe="kirchhoff")


def _analytic_hot_spot(free, fixed, bounds, **kw):
    from .._samples import load_sample

    return AnalyticForward(hot_spot=HotSpot.for_sample(load_sample("silver1")))  # both reference samples share this layer


def _analytic_mirror(free, fixed, bounds, **kw):
    return AnalyticForward(rough=False)


def _analytic_emulator(free, fixed, bounds, *, cache_dir="default", n_train: int = 256, n_test: int = 64, seed: int = 0, progress: bool = False, **kw):
    from ._parameters import make_spec

    base = AnalyticForward()
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


def register_forward(name: str, factory: Callable, description: str) -> None:
    """Make a forward model available by name (CLI ``--forward``, `make_forward`).

    Arguments:
        name: the name.
        factory: ``factory(free, fixed, bounds, **options) -> ForwardModel``; for the tracer,
            typically `build_emulator` over a `CallableForward` with a fixed key.
        description: one line for ``--help``.
    """
    if not name or not callable(factory):
        raise ValueError("register_forward needs a non-empty name and a callable factory")
    FORWARDS[name] = (factory, description)


def make_forward(name: str, free: Sequence[str] = (), fixed: Mapping[str, float] | None = None,
                 bounds: Mapping[str, tuple[float, float]] | None = None, **options) -> ForwardModel:
    """Build the registered forward model `name` for the given free/fixed parameters."""
    if name not in FORWARDS:
        raise ValueError(f"unknown forward model {name!r}; known: {', '.join(FORWARDS)}")
    return FORWARDS[name][0](tuple(free), dict(fixed or {}), dict(bounds or {}), **options)
