"""Charts from seams: cut a mesh along a set of its edges, giving each face its chart and each
face corner its chart vertex (a "wedge": the corners of one mesh vertex joined across uncut
edges), and each chart its own mesh with local vertex ids mapping back to the input's.

A vertex on a seam gets one wedge per side of the seam; a vertex whose faces form several fans
(a non-manifold "bow-tie" vertex) one per fan even without seams, so cutting nothing splits such
vertices (:func:`charts_of_cut` with no cut is how the atlas builder makes its input manifold).
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import scipy.sparse as sp

from .._runtime.errors import MeshError
from ..exact.topology import check_disk

__all__ = ["ChartSplit", "ChartMesh", "charts_of_cut", "face_pairs", "patch_is_disk"]


@dataclasses.dataclass(frozen=True)
class ChartMesh:
    """One chart's own mesh.

    Attributes
    ----------
    faces : (mc,) int64, the input faces of the chart (in input order).
    F : (mc, 3) int64, those faces in local vertex ids.
    wedges : (nc,) int64, the global wedge (UV vertex) of each local vertex.
    vertices : (nc,) int64, the input vertex of each local vertex.
    """

    faces: np.ndarray
    F: np.ndarray
    wedges: np.ndarray
    vertices: np.ndarray

    def part(self, faces):
        """The :class:`ChartMesh` of the chart's faces ``faces`` (rows of ``F``, sorted), and the
        rows of the chart's local vertices it keeps (to take a flattening's part: ``x[rows]``)."""
        faces = np.asarray(faces, dtype=np.int64)
        rows, local = np.unique(self.F[faces], return_inverse=True)
        return ChartMesh(self.faces[faces], local.reshape(-1, 3), self.wedges[rows], self.vertices[rows]), rows

    def disk_loop(self):
        """The boundary loop (k,) of the chart when it is a topological disk, else None."""
        try:
            return check_disk(self.F, len(self.wedges))
        except MeshError:
            return None


@dataclasses.dataclass(frozen=True)
class ChartSplit:
    """A mesh cut into charts.

    Attributes
    ----------
    chart : (m,) int64, the chart of each face (``0 .. count - 1``).
    wedge : (m, 3) int64, the wedge (UV vertex) of each face corner.
    vertex : (w,) int64, the mesh vertex of each wedge.
    count : int, the number of charts.
    """

    chart: np.ndarray
    wedge: np.ndarray
    vertex: np.ndarray
    count: int

    @functools.cached_property
    def _groups(self):
        """``(order, start)``: the faces sorted by chart (input order within one), chart ``c``'s
        being ``order[start[c]:start[c + 1]]``; one sort for all charts, so that taking every
        chart's mesh is linear in the faces overall, not charts times faces."""
        order = np.argsort(self.chart, kind="stable")
        return order, np.searchsorted(self.chart[order], np.arange(self.count + 1))

    def faces_of(self, c: int) -> np.ndarray:
        """(mc,) int64, the faces of chart ``c``, ascending (``np.flatnonzero(chart == c)``)."""
        order, start = self._groups
        return order[start[c]:start[c + 1]]

    def mesh(self, c: int) -> ChartMesh:
        """The :class:`ChartMesh` of chart ``c``."""
        faces = self.faces_of(c)
        wedges, local = np.unique(self.wedge[faces], return_inverse=True)
        return ChartMesh(faces, local.reshape(-1, 3), wedges, self.vertex[wedges])


def _corner_pairs(F, edge_of, edge_faces, keep):
    """Corner pairs ``(i, j)`` (flat corner ids ``3 f + c``) glued across the edges ``keep``."""
    e = np.flatnonzero(keep)
    f1, f2 = edge_faces[e, 0], edge_faces[e, 1]
    c1 = np.argmax(edge_of[f1] == e[:, None], axis=1)
    c2 = np.argmax(edge_of[f2] == e[:, None], axis=1)
    a1, b1 = 3 * f1 + c1, 3 * f1 + (c1 + 1) % 3  # corners of a, b in f1
    b2, a2 = 3 * f2 + c2, 3 * f2 + (c2 + 1) % 3  # f2 runs the edge the other way
    return np.r_[a1, b1], np.r_[a2, b2]


def face_pairs(F):
    """``(a, b, edge, E, edge_of)``: the pairs of faces ``a``, ``b`` of ``F`` (m, 3) that share an
    edge, that edge (a row of ``E``), and ``E``, ``edge_of`` as
    :func:`~geomopt.exact.topology.unique_edges` gives them."""
    from ..exact.topology import unique_edges

    E, _, edge_of = unique_edges(F)
    e = edge_of.ravel()
    f = np.repeat(np.arange(len(F)), 3)
    order = np.argsort(e, kind="stable")
    e, f = e[order], f[order]
    pair = np.flatnonzero(e[1:] == e[:-1])
    return f[pair], f[pair + 1], e[pair], E, edge_of


def patch_is_disk(F, edge_of, faces, n_vertices, n_edges) -> bool:
    """Whether the edge-connected faces ``faces`` of a disk ``F`` (``edge_of`` its faces' edge
    ids, ``n_edges`` of them) form a disk: exactly when their Euler characteristic is 1.  They lie
    in a disk, so (Alexander duality) the characteristic is 1 minus the number of bounded regions
    of the disk they leave out: holes, and at a vertex where the faces meet in two fans, the
    region between the fans that a path of faces from one fan to the other encloses.  Counted by
    marks, not sorts (linear)."""
    def distinct(ids, size):
        seen = np.zeros(size, dtype=bool)
        seen[ids.ravel()] = True
        return int(np.count_nonzero(seen))

    return distinct(F[faces], n_vertices) - distinct(edge_of[faces], n_edges) + len(faces) == 1


def _components(n, i, j):
    from scipy.sparse.csgraph import connected_components

    graph = sp.coo_matrix((np.ones(len(i), dtype=np.int8), (i, j)), shape=(n, n)).tocsr()
    return connected_components(graph, directed=False)


def charts_of_cut(F, edge_of, edge_faces, cut) -> ChartSplit:
    """Cut a mesh along the edges ``cut``.

    Parameters
    ----------
    F : (m, 3) int, consistently oriented triangles, each edge used by at most 2 faces.
    edge_of : (m, 3), edge_faces : (k, 2) as :class:`~geomopt.atlas.seams.EdgeGraph` holds them.
    cut : (k,) bool, the edges to cut (boundary edges are open whatever it says).

    Returns
    -------
    :class:`ChartSplit`
    """
    F = np.asarray(F, dtype=np.int64)
    glued = (edge_faces[:, 1] >= 0) & ~np.asarray(cut, dtype=bool)
    i, j = _corner_pairs(F, edge_of, edge_faces, glued)
    _, wedge = _components(F.size, i, j)
    vertex = np.empty(wedge.max() + 1, dtype=np.int64)
    vertex[wedge] = F.ravel()
    e = np.flatnonzero(glued)
    count, chart = _components(len(F), edge_faces[e, 0], edge_faces[e, 1])
    return ChartSplit(chart.astype(np.int64), wedge.reshape(F.shape).astype(np.int64), vertex, int(count))
