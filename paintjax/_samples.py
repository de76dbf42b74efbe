"""The published reference samples (Silver #1, Silver #2), shipped as package data."""

from __future__ import annotations

import dataclasses
import json
from functools import lru_cache
from importlib import resources

import numpy as np


@dataclasses.dataclass(frozen=True)
class Measured:
    """A value with its standard uncertainty."""

    value: float
    uncertainty: float


@dataclasses.dataclass(frozen=True)
class Sample:
    """Microstructure facts and measured five-angle lightness of a reference paint.

    Lengths in µm, angles in degrees. Uncertain quantities are `Measured`.
    """

    name: str
    description: str
    pvc: Measured
    basecoat_thickness: float
    clearcoat_thickness: float
    binder_index: float
    platelet_thickness: float
    size_d50: float
    size_d10: float
    size_d90: float
    tilt_shape: Measured
    tilt_scale: Measured
    sigma: Measured
    tau: Measured
    aspecular_deg: tuple[float, ...]
    L_star: tuple[float, ...]
    L_star_uncertainty: tuple[float, ...]

    @property
    def mean_tilt_deg(self) -> float:
        """Mean platelet tilt, shape × scale [deg]."""
        return self.tilt_shape.value * self.tilt_scale.value

    @property
    def L_star_array(self) -> np.ndarray:
        return np.asarray(self.L_star, dtype=float)


@lru_cache(maxsize=1)
def _raw() -> dict:
    text = resources.files("paintjax").joinpath("data/samples.json").read_text()
    return json.loads(text)


def sample_names() -> tuple[str, ...]:
    """Names accepted by `load_sample`."""
    return tuple(k for k in _raw() if not k.startswith("_"))


def load_sample(name: str) -> Sample:
    """Load a reference sample by name (`"silver1"`, `"silver2"`).

    Raises:
        ValueError: for an unknown name, listing the known ones.
    """
    raw = _raw()
    key = str(name).lower().replace("#", "").replace(" ", "").replace("_", "")
    if key not in sample_names():
        raise ValueError(f"unknown sample {name!r}; known samples: {', '.join(sample_names())}")
    d = raw[key]
    m = lambda pair: Measured(float(pair[0]), float(pair[1]))  # noqa: E731
    meas = d["measurement"]
    size = d["platelet_size"]
    return Sample(
        name=key,
        description=d["description"],
        pvc=m(d["pvc"]),
        basecoat_thickness=float(d["basecoat_thickness_um"]),
        clearcoat_thickness=float(d["clearcoat_thickness_um"]),
        binder_index=float(d["binder_index"]),
        platelet_thickness=float(d["platelet_thickness_um"]),
        size_d50=float(size["d50_um"]),
        size_d10=float(size["d10_um"]),
        size_d90=float(size["d90_um"]),
        tilt_shape=m(d["tilt_gamma_shape"]),
        tilt_scale=m(d["tilt_gamma_scale_deg"]),
        sigma=m(d["roughness_sigma_um"]),
        tau=m(d["roughness_tau_um"]),
        aspecular_deg=tuple(float(a) for a in meas["aspecular_deg"]),
        L_star=tuple(float(v) for v in meas["L_star"]),
        L_star_uncertainty=tuple(float(v) for v in meas["L_star_uncertainty"]),
    )
