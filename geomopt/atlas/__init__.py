"""Texture atlases of any triangle surface: cut into disk charts, flatten each chart flip-free,
pack the charts into the unit square without overlap, and certify the whole atlas exactly."""

from .build import Atlas, AtlasOptions, make_atlas  # noqa: E402
from .metrics import AtlasMetrics, atlas_metrics, uv_charts  # noqa: E402
