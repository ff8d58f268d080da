"""numba kernels compiled when a caller asks, not when their module is imported.

A :func:`kernel` is plain Python (numba's ``nopython`` subset) until :func:`load`: that imports numba, makes every
kernel a cached ``numba.njit`` function, bound in place of the Python one under every name a kernel module gives it,
and runs the caller's ``loader``, which calls the kernels to load their compiled code for its types from numba's cache
(models/numba_cache.py): about 1 s of CPU together. Both compute the same bits, a SlowPlant step about 30x slower in
Python: a run of a few hundred steps (an FMU checked in a foreign host) is over before numba would have loaded
(``python bench/bench_startup.py``).

numba's cache re-imports a kernel's module by name to rebuild its environment, and this copy of nfal must serve its
own ``numba_cache``. Inside an FMU the carried copy is not in ``sys.modules`` once its bundle loader has set it aside
(fmus/bundle_loader.py), and a host's own nfal may be: so :func:`load` sets the process's nfal modules aside and puts
this copy's packages and kernel modules there while it works, under numba's process-wide compiler lock, then puts
the process's back.
"""

from __future__ import annotations

import contextlib
import sys
import types
from collections.abc import Callable, Iterator

#: This copy of nfal's packages (``nfal``, ``nfal.models``), as they were when it was imported.
_PACKAGES = [sys.modules[__package__.rpartition(".")[0]], sys.modules[__package__]]
#: This copy's kernels, the modules that define them, and the loaders run so far.
_KERNELS: list[Callable] = []
_MODULES: list[types.ModuleType] = []
_LOADED: set[Callable[[], None]] = set()
#: The kernels compiled so far (a kernel module imported after a load is compiled at the next).
_COMPILED: set[Callable] = set()


def kernel(function: Callable) -> Callable:
    """Register ``function`` (defined at a module's top level) as a kernel; it stays Python until :func:`load`."""
    module = sys.modules[function.__module__]
    if module not in _MODULES:
        _MODULES.append(module)
    _KERNELS.append(function)
    return function


def load(loader: Callable[[], None]) -> None:
    """Compile the kernels (once), then run ``loader`` (once), which calls kernels to load them for its types."""
    if loader in _LOADED:
        return
    from numba.core.compiler_lock import global_compiler_lock  # on use: a short run never imports numba

    with global_compiler_lock, _importable():
        if len(_COMPILED) < len(_KERNELS):
            _compile()
        loader()
        _LOADED.add(loader)


def _compile() -> None:
    import numba  # on use: as in load

    from . import numba_cache  # on use: it imports numba

    numba_cache.install()  # before the kernels are made: their compiled code outlives an FMU's temporary folder
    dispatchers = {function: numba.njit(cache=True)(function) for function in _KERNELS if function not in _COMPILED}
    for module in _MODULES:  # every name bound to a kernel, also those imported from another kernel module
        for name, value in list(vars(module).items()):
            if isinstance(value, types.FunctionType) and value in dispatchers:
                setattr(module, name, dispatchers[value])
    _COMPILED.update(dispatchers)


@contextlib.contextmanager
def _importable() -> Iterator[None]:
    """Only this copy's packages and kernel modules in ``sys.modules`` under the package's name (what they import
    comes from this copy); afterwards, the process's modules of that name as before."""
    root = _PACKAGES[0].__name__
    if sys.modules.get(root) is _PACKAGES[0]:  # this copy is the process's nfal: nothing set aside
        yield
        return

    def take_out() -> dict:
        return {name: sys.modules.pop(name) for name in list(sys.modules) if name.partition(".")[0] == root}

    held = take_out()
    sys.modules.update({module.__name__: module for module in [*_PACKAGES, *_MODULES]})
    try:
        yield
    finally:
        take_out()
        sys.modules.update(held)
