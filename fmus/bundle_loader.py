"""Run each FMU on the nfal code and data it carries: the loader at the top of every FMU's slave module.

The build (``fmus/build.py``) copies this file into the FMU as ``resources/nfal_<script>.py``, the
module pythonfmu's runtime imports, and appends one line::

    SlowPlant = load_slave(__file__, "nfal.fmus.slow_plant", "SlowPlant")

Python keeps one module per name in a process, so without this the first FMU a host loads would
serve ``nfal`` to all the others (another nfal version's code, or a folder the host has deleted).
:func:`load_slave` imports the FMU's own ``resources/nfal`` with every ``nfal`` module the process
holds set aside, then puts those back: the FMU's modules keep their own references (imports at
module level bind them), and no other code sees them. Each extracted FMU folder is loaded once per
process; its further instances reuse it. This file uses the standard library only.
"""

from __future__ import annotations

import importlib
import sys
import threading
import types
from pathlib import Path

#: The package every FMU carries its own copy of.
PACKAGE = "nfal"
#: The process-wide registry of loaded FMU folders: {(folder, module): module}, and the lock every load holds (a
#: module in sys.modules because every FMU's copy of this file must find the same one: a lock of each copy's own let
#: two FMUs load at once in two threads, each setting the other's nfal modules aside mid-import).
REGISTRY = "_nfal_fmu_bundles"
#: Import name -> pip name, where they differ.
PIP_NAMES = {"serial": "pyserial", "yaml": "pyyaml"}


def _is_package_module(name: str) -> bool:
    return name == PACKAGE or name.startswith(PACKAGE + ".")


def _registry() -> types.ModuleType:
    """The process's registry: ``bundles`` and ``lock``, each made once (setdefault is atomic: the first one made
    stays; an older FMU's registry, without a lock, gets one)."""
    holder = sys.modules.get(REGISTRY)
    if holder is None:
        holder = sys.modules.setdefault(REGISTRY, types.ModuleType(REGISTRY, "nfal FMU bundles loaded in this process"))
    holder.__dict__.setdefault("bundles", {})
    holder.__dict__.setdefault("lock", threading.RLock())
    return holder


def _import_isolated(folder: Path, module_name: str) -> types.ModuleType:
    """Import ``module_name`` from ``folder`` with the process's nfal modules set aside, then restore them."""
    others = {name: sys.modules.pop(name) for name in list(sys.modules) if _is_package_module(name)}
    sys.path.insert(0, str(folder))
    try:
        return importlib.import_module(module_name)
    finally:
        sys.path.remove(str(folder))
        for name in [name for name in sys.modules if _is_package_module(name)]:
            del sys.modules[name]
        sys.modules.update(others)


def missing_package_message(model: str, error: ModuleNotFoundError) -> str:
    """What to tell the host when the Python that runs the FMU ``model`` lacks a package."""
    top = (error.name or "").split(".")[0]
    pip_name = PIP_NAMES.get(top, top)
    return (f"the {model} FMU needs the Python package '{pip_name}' in the Python that runs it "
            f"({sys.executable}): pip install {pip_name}")


def load_slave(anchor: str, module_name: str, class_name: str) -> type:
    """The slave class ``class_name`` of ``module_name``, imported from the FMU folder of ``anchor``.

    Parameters
    ----------
    anchor : str
        A file in the FMU's ``resources/`` folder (the loader's own ``__file__``).
    module_name : str
        The slave module inside the carried package, e.g. ``"nfal.fmus.slow_plant"``.
    class_name : str
        The slave class, the FMU's model identifier.

    Raises
    ------
    ModuleNotFoundError
        A third-party package is missing; the message names it and the pip command.
    """
    folder = Path(anchor).resolve().parent
    key = (str(folder), module_name)
    registry = _registry()
    with registry.lock:
        bundles = registry.bundles
        if key not in bundles:
            try:
                bundles[key] = _import_isolated(folder, module_name)
            except ModuleNotFoundError as exc:
                if exc.name and _is_package_module(exc.name):
                    raise
                raise ModuleNotFoundError(missing_package_message(class_name, exc), name=exc.name) from exc
        return getattr(bundles[key], class_name)
