"""The atlas's stages stay near-linear in the mesh (issue 50): work that is done per chart, per
seam path or per split touches that chart's or path's part, not the whole mesh again.  Counted
(operations on whole-mesh arrays), not timed."""

from __future__ import annotations

import numpy as np

from geomopt.atlas.charts import ChartSplit
from geomopt.mesh.generators import square_mesh


class _Counted(np.ndarray):
    """An array that counts the ufuncs (comparisons, arithmetic) applied to it whole."""

    calls = 0

    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        type(self).calls += 1
        inputs = tuple(np.asarray(x) if isinstance(x, _Counted) else x for x in inputs)
        return getattr(ufunc, method)(*inputs, **kwargs)


def test_every_chart_mesh_of_a_split_costs_one_pass_over_the_faces_not_one_per_chart():
    _, F = square_mesh(24)  # 1058 triangles, in 46 charts of 23 faces
    F = np.asarray(F)
    chart = (np.arange(len(F)) // 23).astype(np.int64)
    rng = np.random.default_rng(0)
    chart = rng.permutation(chart.max() + 1)[chart]  # charts not in face order
    split = ChartSplit(chart.view(_Counted), np.arange(F.size).reshape(F.shape), F.ravel().copy(), int(chart.max()) + 1)
    _Counted.calls = 0
    meshes = [split.mesh(c) for c in range(split.count)]
    assert _Counted.calls <= 2  # a scan of the whole chart array per chart would be 46
    for c, mesh in enumerate(meshes):
        np.testing.assert_array_equal(mesh.faces, np.flatnonzero(np.asarray(chart) == c))
        np.testing.assert_array_equal(mesh.vertices[mesh.F], F[mesh.faces])
