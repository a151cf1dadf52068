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
(the certificate and the fold-safe step), :mod:`~geomopt.fairing.unfold` (fold removal),
:mod:`~geomopt.fairing.relax` (tangential relaxation),
:mod:`~geomopt.fairing.surface` (closest points and shape measures), :mod:`~geomopt.fairing.options`
and :mod:`~geomopt.fairing.driver`; this package only re-exports.
"""

from typing import TYPE_CHECKING

from .options import BOUNDARIES, METHODS, FairOptions

if TYPE_CHECKING:  # what the lazy names below are, for readers and the API site (griffe reads this)
    from .certificate import FoldCertificate, certify_folds, describe_folds, safe_step
    from .driver import FairDetails, fair, smoothed
    from .unfold import remove_folds
    from .energies import fairing_energy

# public name -> module (imported on first use, PEP 562: the options, which the command line's
# parser reads, load without SciPy or JAX)
_LAZY = {"fair": ".driver", "smoothed": ".driver", "FairDetails": ".driver", "remove_folds": ".unfold",
         "FoldCertificate": ".certificate", "certify_folds": ".certificate", "describe_folds": ".certificate", "safe_step": ".certificate",
         "fairing_energy": ".energies"}

__all__ = ["fair", "smoothed", "FairOptions", "FairDetails", "FoldCertificate", "certify_folds", "describe_folds", "safe_step",
           "remove_folds", "fairing_energy", "METHODS", "BOUNDARIES"]


def __getattr__(name):
    import importlib

    if name not in _LAZY:
        raise AttributeError(f"module 'geomopt.fairing' has no attribute {name!r}")
    value = getattr(importlib.import_module(_LAZY[name], __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
