"""Texture atlases of any triangle surface: cut into disk charts, flatten each chart flip-free,
pack the charts into the unit square without overlap, and certify the whole atlas exactly."""

from ._certify import AtlasCertificate, certify_atlas, chart_boundary_loops  # noqa: E402
from ._pack import Packing, pack_charts, widest_margin  # noqa: E402
from .build import AtlasDetails, AtlasOptions, AtlasPart, make_atlas  # noqa: E402
from .metrics import AtlasMetrics, SeamMetrics, atlas_metrics, seam_metrics, uv_charts  # noqa: E402

__all__ = ["AtlasCertificate", "Packing", "certify_atlas", "chart_boundary_loops", "pack_charts", "widest_margin",
           "AtlasDetails", "AtlasPart", "AtlasOptions", "AtlasMetrics", "atlas_metrics", "make_atlas", "uv_charts",
           "SeamMetrics", "seam_metrics"]
