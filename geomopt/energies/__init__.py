"""Distortion energies, each one density ``psi(J, params)``; see :class:`Energy`."""

from ._densities import chi
from ._energy import (
    REGISTRY,
    Energy,
    arap,
    energy_spec,
    dirichlet,
    garanzha,
    get_energy,
    mips,
    symmetric_dirichlet,
    winslow,
)

__all__ = [
    "Energy", "REGISTRY", "get_energy", "energy_spec", "chi",
    "dirichlet", "symmetric_dirichlet", "mips", "winslow", "arap", "garanzha",
]
