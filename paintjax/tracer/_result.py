"""The result of a tracer run: reflectance factors, L* with batch-means standard errors, the energy ledger."""

from __future__ import annotations

import equinox as eqx
import numpy as np


class TraceResult(eqx.Module):
    """Reflectance factors, L* and the energy ledger of one tracer run (NumPy arrays, per detector).

    `reflectance_factor` is the NEE estimate (for delta platelets: the aperture splat),
    `histogram_reflectance_factor` the finite-aperture histogram of exiting rays (0 for zero
    apertures). Standard errors are batch means over `batches` groups of lanes (bidirectional:
    of each pass, added in quadrature; `batch_reflectance_factor` is then the forward batch plus
    the reverse pool's batch). `rays` counts the rays of all passes; `energy` is per forward ray.
    `resolved` flags, per detector, whether light reached it in at least half the batches.
    """

    aspecular_deg: np.ndarray
    reflectance_factor: np.ndarray
    reflectance_factor_se: np.ndarray
    L_star: np.ndarray
    L_star_se: np.ndarray
    histogram_reflectance_factor: np.ndarray
    histogram_se: np.ndarray
    energy: dict
    rays: int
    seconds: float
    batch_reflectance_factor: np.ndarray  # (batches, m) NEE estimate of each batch
    batch_histogram: np.ndarray  # (batches, m)

    @property
    def resolved(self) -> np.ndarray:
        """Per detector: did light reach it in at least half the batches (`resolved_detectors`)?"""
        return resolved_detectors(self.batch_reflectance_factor)

    def to_dict(self) -> dict:
        """The `paintjax simulate --json` form."""
        return {
            "aspecular_deg": self.aspecular_deg,
            "reflectance_factor": self.reflectance_factor,
            "reflectance_factor_se": self.reflectance_factor_se,
            "L_star": self.L_star,
            "L_star_se": self.L_star_se,
            "energy": dict(self.energy),
            "rays": self.rays,
            "seconds": self.seconds,
            "resolved": self.resolved,
        }


def resolved_detectors(batch_reflectance_factor) -> np.ndarray:
    """Per detector (last axis): True where at least half the batches (first axis) have a nonzero estimate.

    Where most batches saw no light, the estimate rests on a few rare paths and the batch-means
    standard error (even a zero one) says nothing about its error: such an L* is not resolved.
    """
    b = np.asarray(batch_reflectance_factor)
    return 2 * np.count_nonzero(b, axis=0) >= b.shape[0]
