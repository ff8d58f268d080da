"""Build the nfal FMUs with pythonfmu (FMI 2.0) or pythonfmu3 (FMI 3.0), self-contained: :func:`build_fmus`.

Each FMU of :data:`FMU_SCRIPTS` is one slave script of ``fmus/``. pythonfmu puts the FMU's
``resources/`` folder first on ``sys.path`` and imports the script from there, so the build copies in
everything the slave imports from nfal, under the same import names as in the installed package::

    resources/
        nfal_<script>.py        fmus/bundle_loader.py + "<Model> = load_slave(...)": the module pythonfmu
                                imports; it loads this FMU's own nfal/, isolated from any other
        slavemodule.txt         "nfal_<script>" (pythonfmu's loader reads it)
        pythonfmu/              pythonfmu's Python side (added by pythonfmu)
        nfal/__init__.py        a minimal package: docstring and __version__ only (no CLI)
        nfal/errors.py, csvdata.py, realtime.py, cache_folder.py  the foundation modules every layer may import
        nfal/models/            every .py of models/ and data/ (the excitation-form CSV)
        nfal/fmus/__init__.py   base.py (the NfalSlave framework), rig_contract.py (RigSlave) and the slave script
        nfal/hil/               the rig protocol and link, for the HardwareProxy only (HIL_MODULES)
        python.cfg              the Python that built the FMU (executable, libpython, site-packages), which
                                the loader starts in a host without Python; override= (or NFAL_FMU_PYTHON)
                                names another
    binaries/linux64/<Model>.so   the loader (fmus/loader/loader.c): no Python symbols; finds the Python,
                                  loads libpython and the runtime, forwards every FMI call
    binaries/linux64/<Model>_runtime.so   the patched pythonfmu runtime built from fmus/runtime/
                                  (fmus/export_runtime.py)

pythonfmu's and pythonfmu3's stock Windows DLLs (unpatched) are always left out. ``windows_python=`` (``nfal
build --platform win64``) adds our own beside the Linux binaries, cross-compiled with mingw-w64
(:func:`nfal.fmus.export_runtime.windows_runtime_library`), so one FMU serves both::

    binaries/win64/<Model>.dll, <Model>_runtime.dll   (FMI 3.0: binaries/x86_64-windows/)
    resources/python-win64.cfg   the Windows Python they start (fmus/windows_python.py)

``fmi_version=3`` builds the same slave as an FMI 3.0 FMU with pythonfmu3: the layout above (the FMI 3.0
binaries under ``binaries/x86_64-linux/``: the loader, and the patched pythonfmu3 runtime built from
fmus/runtime3/), plus ``pythonfmu/`` (pythonfmu's
Python side, which NfalSlave builds on), ``pythonfmu3/`` (added by pythonfmu3) and the generated slave module
``nfal3_<script>.py`` (:func:`nfal.fmus.fmi3.fmi3_script`), named in ``slavemodule.txt``.

Third-party packages (numpy, scipy, numba, python-control; pyserial and cobs for the proxy) come from
the Python environment that runs the FMU (a Python host's own, else the one python.cfg records); a missing one fails
fmi2Instantiate with a logged line naming it and its pip command. Every FMU runs the nfal code it
carries, whatever else the host process has imported (``fmus/bundle_loader.py``).

An FMU is rebuilt only when it is missing or older than one of its sources (the script, the copied
files, this file); ``force=True`` rebuilds regardless. What is built is kept in the nfal cache
(``fmus/<digest>/``, by the sources' content, the builders' versions and the Python the FMU records; the newest
:data:`KEPT_BUILDS` of each FMU), and a build of the same is a copy from there (``python bench/bench_startup.py``
times both, after a warm-up build: pythonfmu imports the slave to describe it). Builds go to a temporary file
that replaces the FMU in one step, so a reader never sees half an archive.
"""

from __future__ import annotations

import logging
import os
import shutil
import sys
import tempfile
import zipfile
from pathlib import Path
from typing import Iterable

import pythonfmu
import pythonfmu3
from pythonfmu import FmuBuilder as Fmi2Builder
from pythonfmu3 import FmuBuilder as Fmi3Builder

import nfal
import nfal.hil
import nfal.models
from nfal.errors import InvalidParameterError, RuntimeBuildError
from nfal.fmus.export_runtime import (LOADER_WINDOWS_HEADER, PYTHON_CONFIG, PYTHON_OVERRIDE_ENV, RUNTIME_SUFFIX,
                                      RUNTIMES, WINDOWS_PYTHON_CONFIG, loader_library, python_config,
                                      python_settings, runtime_library, windows_loader_library,
                                      windows_runtime_library)
from nfal.fmus.windows_python import windows_settings
from nfal.fmus.fmi3 import fmi3_script
from nfal.cache_folder import cache_root, write_in_one_step
from nfal.models.disk_cache import digest

logger = logging.getLogger(__name__)

#: FMU (model identifier) -> slave script in fmus/. A user may add entries (script paths are
#: resolved against fmus/ unless absolute).
FMU_SCRIPTS: dict[str, str] = {
    "SlowPlant": "slow_plant.py",
    "ReynoldsPlant": "reynolds_plant.py",
    "Controller": "controller.py",
    "ResonanceTracker": "resonance_tracker.py",
    "SensorChain": "sensor_chain.py",
    "HardwareProxy": "hardware_proxy.py",
    "ReferenceGenerator": "reference_generator.py",
}
#: The FMUs the simulated Fig. 7 structures (fig7_slow, fig7_reynolds) use between them: all but the HardwareProxy.
SIMULATION_FMUS = tuple(name for name in FMU_SCRIPTS if name != "HardwareProxy")
#: What every FMU copies from fmus/ beside its script.
FMUS_SUPPORT = ("__init__.py", "base.py", "rig_contract.py", "fmi3.py")
#: The slave module's loader (the module pythonfmu imports; fmus/bundle_loader.py).
BUNDLE_LOADER = "bundle_loader.py"
#: Prefix of the loader module inside the FMU (of the generated FMI 3.0 script: FMI3_PREFIX).
MODULE_PREFIX, FMI3_PREFIX = "nfal_", "nfal3_"
#: The FMI versions ``build_fmu`` makes: 2 with pythonfmu, 3 with pythonfmu3 (fmus/fmi3.py).
FMI_VERSIONS = (2, 3)
#: Modules of nfal.hil an FMU carries beside nfal.models (the host's side of the rig protocol).
HIL_MODULES: dict[str, tuple[str, ...]] = {"HardwareProxy": ("__init__.py", "protocol.py", "link.py")}

FMUS_DIR = Path(__file__).resolve().parent
#: The package root's foundation modules (importable by every layer, docs/architecture.md): every FMU carries them.
FOUNDATION_MODULES = tuple(Path(nfal.__file__).resolve().parent / name
                           for name in ("errors.py", "csvdata.py", "realtime.py", "cache_folder.py"))


def _models_dir() -> Path:
    """The folder of nfal.models (models/ in a checkout or editable install, nfal/models in a wheel)."""
    return Path(nfal.models.__file__).resolve().parent


def _hil_files(name: str) -> list[Path]:
    root = Path(nfal.hil.__file__).resolve().parent
    return [root / module for module in HIL_MODULES.get(name, ())]


def _model_files() -> list[Path]:
    root = _models_dir()
    files = sorted(root.glob("*.py")) + sorted(p for p in (root / "data").rglob("*") if p.is_file())
    return [p for p in files if "__pycache__" not in p.parts]


def script_path(name: str) -> Path:
    """The slave script of the FMU ``name`` (one of :data:`FMU_SCRIPTS`)."""
    if name not in FMU_SCRIPTS:
        raise InvalidParameterError("FMU name", name, f"one of {sorted(FMU_SCRIPTS)}")
    path = Path(FMU_SCRIPTS[name])
    return path if path.is_absolute() else FMUS_DIR / path


def sources(name: str, fmi_version: int = 2) -> list[Path]:
    """Every file the FMU ``name`` is built from (its staleness is judged against these)."""
    return [script_path(name), Path(__file__).resolve(), FMUS_DIR / BUNDLE_LOADER, FMUS_DIR / "export_runtime.py",
            *FOUNDATION_MODULES, *(FMUS_DIR / f for f in FMUS_SUPPORT), *_model_files(), *_hil_files(name),
            *RUNTIMES[fmi_version].source_files()]


def is_up_to_date(fmu: Path, name: str, fmi_version: int = 2, *, windows: Path | None = None) -> bool:
    """Whether ``fmu`` exists, is newer than every source of ``name`` (built for ``fmi_version``) and, with
    ``windows`` (the root of a Windows CPython), has Windows binaries that start that Python."""
    if not fmu.is_file():
        return False
    built = fmu.stat().st_mtime
    windows_sources = [LOADER_WINDOWS_HEADER, FMUS_DIR / "windows_python.py"] if windows else []
    if not all(source.stat().st_mtime < built for source in sources(name, fmi_version) + windows_sources):
        return False
    if not windows:
        return True
    with zipfile.ZipFile(fmu) as archive:  # built for this Windows Python (the cfg names it)
        names = archive.namelist()
        if _windows_binary(name, fmi_version) not in names or f"resources/{WINDOWS_PYTHON_CONFIG}" not in names:
            return False
        return archive.read(f"resources/{WINDOWS_PYTHON_CONFIG}").decode() == python_config(
            windows_settings(windows), windows=True)


def _windows_binary(name: str, fmi_version: int) -> str:
    return f"binaries/{RUNTIMES[fmi_version].windows_platform}/{name}.dll"


def _minimal_package_init() -> str:
    return ('"""nfal, as carried inside an FMU: its foundation modules, nfal.models and nfal.fmus.base only '
            '(see fmus/build.py)."""'
            f'\n\n__version__ = "{nfal.__version__}"\n')


def _stage(name: str, stage: Path) -> Path:
    """Lay out the nfal package with the script, and the loader module, in ``stage``; return the loader."""
    script = script_path(name)
    if not script.is_file():
        raise InvalidParameterError(f"script of {name}", str(script), "an existing slave script")
    package = stage / "nfal"
    (package / "models" / "data").mkdir(parents=True)
    (package / "fmus").mkdir()
    (package / "__init__.py").write_text(_minimal_package_init(), encoding="utf-8")
    for module in FOUNDATION_MODULES:
        shutil.copy2(module, package / module.name)
    models = _models_dir()
    for source in _model_files():
        target = package / "models" / source.relative_to(models)
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(source, target)
    for support in FMUS_SUPPORT:
        shutil.copy2(FMUS_DIR / support, package / "fmus" / support)
    hil = _hil_files(name)
    if hil:
        (package / "hil").mkdir()
        for source in hil:
            shutil.copy2(source, package / "hil" / source.name)
    shutil.copy2(script, package / "fmus" / script.name)
    staged = stage / f"{MODULE_PREFIX}{script.stem}.py"
    loader = (FMUS_DIR / BUNDLE_LOADER).read_text(encoding="utf-8")
    staged.write_text(f'{loader}\n\n{name} = load_slave(__file__, "nfal.fmus.{script.stem}", "{name}")\n',
                      encoding="utf-8")
    return staged


def _with_runtime(built: Path, name: str, target: Path, fmi_version: int, windows_python: Path | None) -> None:
    """Copy the FMU ``built`` to ``target`` with our binaries for Linux (the loader as ``<name>.so``, the
    patched runtime of ``fmi_version`` beside it as ``<name>_runtime.so``) and ``resources/python.cfg``
    (the Python that runs it, :func:`nfal.fmus.export_runtime.python_settings`); with ``windows_python`` (the
    root of a Windows CPython) the same for win64 (``.dll``, ``python-win64.cfg``); the builders' stock binaries
    are left out."""
    platform = RUNTIMES[fmi_version].platform
    binary = f"binaries/{platform}/{name}.so"
    settings = python_settings()
    with zipfile.ZipFile(built) as source, zipfile.ZipFile(target, "w", zipfile.ZIP_DEFLATED) as out:
        replaced = False
        for item in source.infolist():
            if item.filename == binary:
                replaced = True
            elif not item.filename.startswith("binaries/"):
                out.writestr(item, source.read(item))
        if not replaced:  # the builder's layout changed: the stock binary would stay beside ours
            raise RuntimeBuildError(f"{built.name} has no {binary} to replace with the patched runtime")
        out.write(loader_library(fmi_version), binary)
        out.write(runtime_library(fmi_version), f"binaries/{platform}/{name}{RUNTIME_SUFFIX}")
        out.writestr(f"resources/{PYTHON_CONFIG}", python_config(settings))
        if windows_python is not None:
            out.write(windows_loader_library(fmi_version, windows_python), _windows_binary(name, fmi_version))
            out.write(windows_runtime_library(fmi_version, windows_python),
                      f"binaries/{RUNTIMES[fmi_version].windows_platform}/{name}_runtime.dll")
            out.writestr(f"resources/{WINDOWS_PYTHON_CONFIG}",
                         python_config(windows_settings(windows_python), windows=True))


def _fmi3_stage(name: str, stage: Path, staged: Path) -> tuple[Path, list[Path]]:
    """Add the FMI 3.0 script around the staged FMI 2.0 one, and pythonfmu's Python side (which the
    slave's base class needs; pythonfmu3 adds its own); return the script and the project files."""
    runtime = stage / "pythonfmu"
    runtime.mkdir()
    for module in Path(pythonfmu.__file__).parent.glob("*.py"):
        shutil.copy2(module, runtime / module.name)
    script = stage / f"{FMI3_PREFIX}{script_path(name).stem}.py"
    script.write_text(fmi3_script(name, staged.stem, f"see {staged.name}"), encoding="utf-8")
    return script, [stage / "nfal", runtime, staged]


def build_fmu(name: str, out_dir: str | os.PathLike, *, force: bool = False, fmi_version: int = 2,
              windows_python: Path | None = None) -> Path:
    """Build the FMU ``name`` into ``out_dir``/``name``.fmu (kept if up to date unless ``force``),
    FMI 2.0 (pythonfmu) or, with ``fmi_version=3``, FMI 3.0 (pythonfmu3, fmus/fmi3.py); with Windows binaries
    too for ``windows_python``, the root of a Windows CPython (:func:`nfal.fmus.windows_python.windows_python`)."""
    if fmi_version not in FMI_VERSIONS:
        raise InvalidParameterError("fmi_version", fmi_version, f"one of {FMI_VERSIONS}")
    FmuBuilder = Fmi3Builder if fmi_version == 3 else Fmi2Builder  # noqa: N806 - the class, as pythonfmu names it
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    target = out / f"{name}.fmu"
    if not force and is_up_to_date(target, name, fmi_version, windows=windows_python):
        logger.debug("%s is up to date", target)
        return target
    settings = python_settings()
    if not settings.get("libpython"):
        logger.warning("the Python building %s (%s) has no shared libpython: a host without Python cannot run "
                       "the FMU until %s (or override= in resources/%s) names one that has", name,
                       settings.get("executable"), PYTHON_OVERRIDE_ENV, PYTHON_CONFIG)
    cached = cache_root() / "fmus" / _build_key(name, fmi_version, windows_python) / target.name
    if not force and cached.is_file():
        try:  # a new file (modification time now): newer than its sources, and than archives packed before it
            write_in_one_step(target, lambda path: shutil.copyfile(cached, path))
            logger.debug("built %s (from the cache: %s)", target, cached.parent)
            return target
        except FileNotFoundError:  # pruned by another process meanwhile: built below
            pass
    logger.info("building %s (pythonfmu%s)", target, "3" if fmi_version == 3 else "")
    with tempfile.TemporaryDirectory(prefix=f"nfal_build_{name}_") as temp:
        stage = Path(temp) / "stage"
        stage.mkdir()
        staged = _stage(name, stage)
        script, project_files = staged, [stage / "nfal"]
        if fmi_version == 3:
            script, project_files = _fmi3_stage(name, stage, staged)
        path_before = list(sys.path)
        sys.modules.pop(staged.stem, None)  # a slave module of a loaded FMU must not stand in for the new script
        try:
            built = FmuBuilder.build_FMU(script, dest=Path(temp) / f"{name}.fmu", project_files=project_files)
        finally:
            sys.path[:] = path_before  # the builder inserts the script's folder for good
            sys.modules.pop(staged.stem, None)
        write_in_one_step(target, lambda path: _with_runtime(built, name, path, fmi_version, windows_python))
    try:
        write_in_one_step(cached, lambda path: shutil.copyfile(target, path))
        _prune(cached.parent.parent, target.name)
    except OSError as exc:  # a cache that cannot be written is no reason to fail the build
        logger.warning("the FMU %s is not kept in the nfal cache: %s", name, exc)
    logger.debug("built %s", target)  # "building" said it at the start
    return target


def _build_key(name: str, fmi_version: int, windows_python: Path | None) -> str:
    """What an FMU built now would be made of: every source (:func:`sources`) by content, the nfal version it
    carries, the builders' versions and the Python (and Windows Python) it records."""
    files = sources(name, fmi_version) + ([LOADER_WINDOWS_HEADER, FMUS_DIR / "windows_python.py"]
                                          if windows_python else [])
    recorded = [python_config(python_settings())]
    if windows_python is not None:
        recorded.append(python_config(windows_settings(windows_python), windows=True))
    return digest(name, fmi_version, _minimal_package_init(), pythonfmu.__version__, pythonfmu3.__version__,
                  *recorded, *(part for path in files for part in (path.name, path.read_bytes())))


#: Builds the cache keeps of each FMU file name (every edit of a source makes a new one; the oldest go).
KEPT_BUILDS = 8


def _prune(root: Path, file_name: str) -> None:
    """Remove all but the newest :data:`KEPT_BUILDS` cached builds named ``file_name`` under ``root``."""
    builds = sorted(root.glob(f"*/{file_name}"), key=lambda path: path.stat().st_mtime, reverse=True)
    for old in builds[KEPT_BUILDS:]:
        shutil.rmtree(old.parent, ignore_errors=True)


def build_fmus(out_dir: str | os.PathLike, names: Iterable[str] | None = None, *, force: bool = False,
               fmi_version: int = 2, windows_python: Path | None = None) -> dict[str, Path]:
    """Build the FMUs ``names`` (default: all of :data:`FMU_SCRIPTS`) into ``out_dir``.

    Parameters
    ----------
    out_dir : path
        Destination folder (created if missing).
    names : iterable of str, optional
        Model identifiers, e.g. ``["SlowPlant", "Controller"]``.
    force : bool
        Rebuild even the FMUs newer than their sources.
    fmi_version : {2, 3}
        FMI 2.0 (pythonfmu) or FMI 3.0 co-simulation (pythonfmu3; the same slaves, :mod:`nfal.fmus.fmi3`).
    windows_python : path, optional
        The root of a Windows CPython: the FMUs carry win64 binaries that start it, beside the Linux ones.

    Returns
    -------
    dict
        {name: path of the .fmu}.
    """
    names = list(FMU_SCRIPTS) if names is None else list(names)
    for name in names:
        script_path(name)  # unknown names fail before anything is built
    return {name: build_fmu(name, out_dir, force=force, fmi_version=fmi_version, windows_python=windows_python)
            for name in names}
