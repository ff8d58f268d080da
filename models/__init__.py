"""Pure numerics of near-field acoustic levitation: no FMI, no ports, no result files."""

from .numba_cache import install as _install_numba_cache

_install_numba_cache()  # before any kernel module: the FMUs' copies share the checkout's compiled kernels
