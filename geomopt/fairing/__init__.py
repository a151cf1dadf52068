"""Surface and curve smoothing as energies, with no face ever folded (issue 52).

:func:`fair` smooths a triangle surface (closed, with boundary, several components) or a
polyline (closed or open) by one of the lectures' methods (:data:`METHODS`: Laplacian and
Taubin steps, implicit fairing, Laplacian mesh optimization, the bi-Laplacian energy with a data
term, spectral filtering, tangential smoothing, and tangential relaxation onto the input
surface) and certifies the output exactly: each face positively oriented against its corners'
area-weighted vertex normals (:class:`FoldCertificate`).  :func:`smoothed` is the method alone,
differentiable with JAX; :func:`fairing_energy` is the energy it minimises, to compose with others.

One module per job: :mod:`~geomopt.fairing.operators` (Laplacians and masses),
:mod:`~geomopt.fairing.solve` (the differentiable sparse solve), :mod:`~geomopt.fairing.methods`
(the methods), :mod:`~geomopt.fairing.energies` (the energies), :mod:`~geomopt.fairing.certificate`
(the certificate and the fold-safe step), :mod:`~geomopt.fairing.relax` (tangential relaxation),
:mod:`~geomopt.fairing.surface` (closest points and shape measures), :mod:`~geomopt.fairing.options`
and :mod:`~geomopt.fairing.driver`; this package only re-exports.
"""

from .certificate import FoldCertificate, certify_folds, safe_step
from .driver import FairDetails, fair, remove_folds, smoothed
from .energies import fairing_energy
from .options import BOUNDARIES, METHODS, FairOptions

__all__ = ["fair", "smoothed", "FairOptions", "FairDetails", "FoldCertificate", "certify_folds", "safe_step",
           "remove_folds", "fairing_energy", "METHODS", "BOUNDARIES"]
