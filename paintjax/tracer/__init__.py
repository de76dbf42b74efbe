"""The ray-batch Monte Carlo tracer: a platelet basecoat under a clearcoat, seen by the instrument.

In: a `PlateletArray` and its `UniformGrid`, a platelet BRDF, a `Geometry`, the coat. Out: a
`TraceResult` (reflectance factors, L* with batch-means standard errors, the energy ledger),
optionally combined over wavelengths as the instrument does; a deterministic single-scatter
reference of one tile to check it against; and a per-stage time profile of the wavefront step.
"""

from ._options import (
    DEFAULT_LANES,
    LEDGER_KEYS,
    MAX_CREATED_ENERGY,
    REVERSE_SHARE_BY_ASPECULAR,
    EnergyCreationError,
    TracerOptions,
    default_lanes,
    detector_reverse_shares,
)
from ._plain import plain_trace_counts, plain_trace_seconds
from ._profile import PROFILE_PARENTS, PROFILE_STAGES, profile_wavefront_step
from ._result import TraceResult
from ._scene import build_scene
from ._spectral import SPECTRAL_NODES_NM, combine_spectral, lab_from_xyz, spectral_node_weights
from ._tile_single_scatter import tile_mirror_single_scatter
from ._trace import check_ray_count, lightness_with_se, trace

__all__ = [
    "DEFAULT_LANES",
    "default_lanes",
    "LEDGER_KEYS",
    "MAX_CREATED_ENERGY",
    "EnergyCreationError",
    "TracerOptions",
    "REVERSE_SHARE_BY_ASPECULAR",
    "detector_reverse_shares",
    "plain_trace_seconds",
    "plain_trace_counts",
    "PROFILE_STAGES",
    "PROFILE_PARENTS",
    "profile_wavefront_step",
    "TraceResult",
    "build_scene",
    "SPECTRAL_NODES_NM",
    "combine_spectral",
    "lab_from_xyz",
    "spectral_node_weights",
    "tile_mirror_single_scatter",
    "check_ray_count",
    "lightness_with_se",
    "trace",
]
