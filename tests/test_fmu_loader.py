"""The FMU loader's build side (fmus/export_runtime.py): the FMI functions read from the headers, the
forwarders generated from them, and the Python settings an FMU records. The loader itself runs in
tests/test_host_compatibility.py (hosts with nothing set up) and tests/test_fmu_misuse.py."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy
import pytest

from nfal.errors import RuntimeBuildError
from nfal.fmus.export_runtime import (PYTHON_OVERRIDE_ENV, RUNTIMES, fmi_functions, forwarders_source, python_config,
                                      python_settings)


def functions(version: int):
    source = RUNTIMES[version].function_types.read_text(encoding="latin-1")
    return {name: (returns, parameters) for returns, name, parameters in fmi_functions(source)}


def test_every_fmi2_function_is_read_with_named_arguments():
    fmi2 = functions(2)
    assert len(fmi2) == 44  # every fmi2...TYPE of fmi2FunctionTypes.h (co-simulation and model exchange)
    returns, parameters = fmi2["fmi2Instantiate"]
    assert returns == "fmi2Component"
    assert [argument for _, argument in parameters] == [f"a{k}" for k in range(7)]
    assert parameters[4][0] == "const fmi2CallbackFunctions* a4"
    assert fmi2["fmi2SetReal"][1][1][0] == "const fmi2ValueReference a1[]"
    assert fmi2["fmi2GetVersion"] == ("const char*", [])


def test_every_fmi3_function_is_read_with_its_own_argument_names():
    fmi3 = functions(3)
    assert len(fmi3) == 75
    returns, parameters = fmi3["fmi3InstantiateCoSimulation"]
    assert returns == "fmi3Instance" and len(parameters) == 12
    assert [argument for _, argument in parameters][-3:] == ["instanceEnvironment", "logMessage", "intermediateUpdate"]
    assert fmi3["fmi3FreeInstance"] == ("void", [("fmi3Instance instance", "instance")])


@pytest.mark.parametrize("version", [2, 3])
def test_forwarders_cover_what_the_runtime_exports_and_guard_the_instance(version):
    listed = fmi_functions(RUNTIMES[version].function_types.read_text(encoding="latin-1"))
    exported = {f"fmi{version}GetVersion", f"fmi{version}FreeInstance", f"fmi{version}DoStep",
                "fmi2Instantiate" if version == 2 else "fmi3InstantiateCoSimulation"}
    source = forwarders_source(listed, exported, version)
    assert source.count("nfal_runtime_symbol(") == len(exported)
    assert f"return fmi{version}Version;" in source  # answered without Python
    first = "a0" if version == 2 else "instance"
    assert f"if (nfal_live_remove({first})) nfal_table.fmi{version}FreeInstance({first});" in source
    assert f"if (!nfal_live_has({first})) return fmi{version}Error;" in source
    assert "nfal_load(message, sizeof message)" in source and "nfal_live_add(instance)" in source
    assert f"fmi{version}SetReal" not in source and "fmi3SetFloat64" not in source  # not exported: not forwarded


def test_the_recorded_settings_are_this_pythons():
    settings = python_settings()
    assert settings["executable"] == sys.executable
    assert settings["version"] == f"{sys.version_info[0]}.{sys.version_info[1]}"
    assert settings["prefix"] == sys.prefix and settings["base_prefix"] == sys.base_prefix
    assert str(Path(numpy.__file__).parent.parent) in settings["site"].split(os.pathsep)
    assert settings["libpython"] == "" or Path(settings["libpython"]).is_file()


def test_python_config_has_an_empty_override_and_says_how_to_set_one():
    text = python_config({"executable": "/x/bin/python", "libpython": "/x/lib/libpython3.11.so.1.0", "site": "/a:/b"})
    lines = text.splitlines()
    assert "override=" in lines and "executable=/x/bin/python" in lines and "site=/a:/b" in lines
    assert PYTHON_OVERRIDE_ENV in text and "Py_ENABLE_SHARED" in text


def test_settings_of_a_python_that_does_not_run_are_an_error(tmp_path):
    broken = tmp_path / "python"
    broken.write_text("#!/bin/sh\necho broken >&2\nexit 3\n")
    broken.chmod(0o755)
    with pytest.raises(RuntimeBuildError, match="broken"):
        python_settings(broken)


@pytest.mark.slow  # CMake and a C++ build of the runtime
@pytest.mark.parametrize("version", [2, 3])
def test_the_runtime_builds_from_a_cold_cache_with_this_pythons_headers(version, tmp_path, monkeypatch):
    """A fresh machine has no cached runtime: it must build with the headers of the Python that runs the build, also
    when its venv is not activated (`venv/bin/nfal build` run directly: with pyenv's shims on PATH, CMake's own
    search missed the interpreter's headers and failed; the suite's warm cache had hidden it)."""
    from nfal.fmus.export_runtime import exported_functions, runtime_library

    monkeypatch.setenv("NFAL_CACHE_DIR", str(tmp_path))
    # the venv not activated, the rest of PATH as it is (here: pyenv's shims, whose python3-config misled CMake)
    monkeypatch.setenv("PATH", os.pathsep.join(p for p in os.environ["PATH"].split(os.pathsep)
                                               if not p.startswith(sys.prefix)))
    monkeypatch.delenv("VIRTUAL_ENV", raising=False)
    # CMake still configures and builds from the sources, the preprocessor still needs the headers; the compiler's
    # output comes from ccache where the suite built these sources before (tests/conftest.py)
    library = runtime_library(version)
    assert library.is_file() and tmp_path in library.parents
    assert f"fmi{version}DoStep" in exported_functions(library)
    # on Python's stable ABI whatever cmake PATH finds first (here Debian's 3.25, with which the FMI 2.0 runtime's
    # CMakeLists.txt built it on the full API; FMI 3.0's always asks for it): Py_CompileString is a function of the
    # limited API, and a macro for Py_CompileStringExFlags in the full one
    imported = subprocess.run(["nm", "-D", "--undefined-only", str(library)], capture_output=True, text=True,
                              check=True).stdout.split()
    assert "Py_CompileStringExFlags" not in imported
