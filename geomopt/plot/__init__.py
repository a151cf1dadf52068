"""Pictures and saved results: the output floor, on top of everything it draws or writes.

Figures (matplotlib, no pyplot state): a UV map as a checkerboard texture on the surface beside
its layout coloured by distortion, a map onto the sphere, an atlas, untangling start/result
pictures with inverted elements marked, and convergence plots.  Each picture has a ``*_figure``
function returning a :class:`matplotlib.figure.Figure` (shown inline by Jupyter) and a
``save_*`` function that saves it to a path (atomically, in the format its extension names:
``.png``, ``.pdf``, ``.svg``) or into an open binary file (then ``format`` is required).
:func:`show` draws a map in polyscope or pyvista instead (interactive, or a screenshot taken
off-screen), when one of them is installed (``pip install "geomopt[view]"``).
:func:`geomopt.save` writes a result's map file and picture.

One module per job: ``_figures`` (the matplotlib figures), ``_render`` (the NumPy rasterizer
and renders), ``_compose`` (PNG pictures composed without matplotlib), ``_view`` (the
viewers), ``_save`` (a result's map file and picture); this package only re-exports.
"""

from ._figures import (INVERTED, atlas_figure, convergence_figure, distortion, flat_tripcolor, layout_figure,
                       param_figure, save_atlas_figure, save_convergence, save_layout, save_param_figure,
                       save_sphere_figure, save_untangle_figure, sphere_figure, untangle_figure)
from ._view import show

__all__ = [
    "distortion", "param_figure", "save_param_figure", "layout_figure", "save_layout", "untangle_figure",
    "save_untangle_figure", "convergence_figure", "save_convergence", "sphere_figure", "save_sphere_figure",
    "atlas_figure", "save_atlas_figure", "show", "flat_tripcolor", "INVERTED",
]
