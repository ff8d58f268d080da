"""Our FMUs in non-Python hosts, run many times with nothing set up: no crash (exit code counted), the
results FMPy gives.

Every host runs as ``env -i PATH=/usr/bin:/bin HOME=$HOME`` would run it (``host_check.bare_environment``):
the FMU's loader (fmus/loader/loader.c) finds the Python the FMU was built with, from any folder and with
another Python active; an override naming a Python that is not there is one logged line and an error.
pythonfmu 0.7.0's runtime crashed such hosts at exit in about 4 runs of 10 (docs/cosimulation.md,
"Crash at exit"); the runtime our FMUs ship (fmus/runtime/) must not. The suite runs each case
RUNS times (5 runs miss a crash of 4 in 10 with probability 0.08; the double free behind it is shown in every run
by tests/test_fmu_misuse.py's valgrind test); ``python bench/host_compat.py`` makes the 50-run measurement the doc
quotes.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import simulate_fmu

from nfal.errors import DataFormatError, HostUnavailableError
from nfal.fmus import build
from nfal.fmus.export_runtime import PYTHON_CONFIG, PYTHON_OVERRIDE_ENV, RUNTIME_SUFFIX, RUNTIMES, exported_functions
from nfal.apps.host_check import bare_environment, compile_c_host, ecos_executable, run_in_c_host, run_in_ecos
from nfal.orchestration.ssp_archive import pack

from helpers.probe_fmus import build_probe

# one worker runs the module (its xdist group), so that its module fixtures are built once
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("host_compatibility"),
              pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the loader is built for Linux only")]

FIG7_FMUS = list(build.SIMULATION_FMUS)
RUNS = 5
STOP_S, STEP_S = 0.01, 5e-4
ECOS_STOP_S = 0.2


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    return build.build_fmus(tmp_path_factory.mktemp("hosts"), FIG7_FMUS)


@pytest.fixture(scope="module")
def fmus3(tmp_path_factory):
    """SlowPlant and Controller as FMI 3.0 FMUs."""
    return build.build_fmus(tmp_path_factory.mktemp("hosts3"), ["SlowPlant", "Controller"], fmi_version=3)


@pytest.fixture(scope="module")
def other_python(tmp_path_factory) -> Path:
    """Another Python's venv, without numpy: the system's Python if there is one, else this one's base."""
    base = Path("/usr/bin/python3") if Path("/usr/bin/python3").is_file() else Path(sys.base_prefix) / "bin" / "python3"
    venv = tmp_path_factory.mktemp("other") / "venv"
    subprocess.run([str(base), "-m", "venv", "--without-pip", str(venv)], check=True, capture_output=True)
    python = venv / "bin" / "python"
    assert subprocess.run([str(python), "-c", "import numpy"], capture_output=True).returncode != 0
    return python


def another_python_active(python: Path) -> dict[str, str]:
    """As after ``source <venv>/bin/activate`` of ``python``'s venv, and nothing else set up."""
    venv = python.parent.parent
    return bare_environment(PATH=f"{venv / 'bin'}:/usr/bin:/bin", VIRTUAL_ENV=str(venv))


def fmpy_outputs(fmu: Path, outputs, stop_time: float = STOP_S) -> dict:
    reference = simulate_fmu(str(fmu), stop_time=stop_time, step_size=STEP_S, output_interval=STEP_S,
                             output=list(outputs))
    return {output: pytest.approx(float(reference[output][-1]), rel=1e-12, abs=0) for output in outputs}


def with_config(fmu: Path, target: Path, **settings: str) -> Path:
    """A copy of ``fmu`` at ``target`` whose resources/python.cfg has ``settings`` (e.g. override=...)."""
    name = f"resources/{PYTHON_CONFIG}"
    with zipfile.ZipFile(fmu) as source, zipfile.ZipFile(target, "w") as out:
        for item in source.infolist():
            data = source.read(item)
            if item.filename == name:
                lines = [line for line in data.decode().splitlines() if line.split("=", 1)[0] not in settings]
                data = "\n".join(lines + [f"{key}={value}" for key, value in settings.items()]).encode() + b"\n"
            out.writestr(item, data)
    return target


@pytest.mark.parametrize("fmi_version", [2, 3])
def test_the_binary_a_host_loads_has_no_python_symbols(fmi_version, fmus, fmus3, tmp_path):
    """The loader needs no libpython to load; it exports what the runtime beside it exports; no untested platform."""
    if shutil.which("nm") is None:
        pytest.skip("needs nm (binutils)")
    fmu = (fmus if fmi_version == 2 else fmus3)["SlowPlant"]
    with zipfile.ZipFile(fmu) as archive:
        archive.extractall(tmp_path)
        binaries = {name for name in archive.namelist() if name.startswith("binaries/")}
    platform = RUNTIMES[fmi_version].platform
    assert binaries == {f"binaries/{platform}/SlowPlant.so", f"binaries/{platform}/SlowPlant{RUNTIME_SUFFIX}"}
    loader = tmp_path / "binaries" / platform / "SlowPlant.so"
    undefined = subprocess.run(["nm", "-D", "--undefined-only", str(loader)], capture_output=True, text=True,
                               check=True).stdout.split()
    assert not [symbol for symbol in undefined if symbol.lstrip("_").startswith("Py")]
    runtime = exported_functions(tmp_path / "binaries" / platform / f"SlowPlant{RUNTIME_SUFFIX}")
    assert exported_functions(loader) == runtime and len(runtime) >= (30 if fmi_version == 2 else 60)


def host_or_skip(make, folder):
    """The host ``make(folder)`` builds, or a skip naming what this machine lacks (compiler, libtbb12)."""
    try:
        return make(folder)
    except HostUnavailableError as exc:
        pytest.skip(str(exc))


@pytest.fixture(scope="module")
def c_host(tmp_path_factory):
    return host_or_skip(compile_c_host, tmp_path_factory.mktemp("c_host"))


@pytest.fixture(scope="module")
def c_host3(tmp_path_factory):
    return host_or_skip(lambda folder: compile_c_host(folder, 3), tmp_path_factory.mktemp("c_host3"))


@pytest.mark.parametrize("name", FIG7_FMUS)
def test_every_fmu_runs_in_a_c_host_without_a_crash(name, fmus, c_host, tmp_path):
    """Load, simulate 10 ms, free, dlclose, exit, with nothing set up: RUNS times; every output equal to
    FMPy's, every run."""
    runs = run_in_c_host(c_host, fmus[name], tmp_path, runs=RUNS, stop_time=STOP_S, step_size=STEP_S)
    assert runs.crashes == 0, f"exit codes {runs.exit_codes}:\n{runs.first_failure[-3000:]}"
    expected = fmpy_outputs(fmus[name], runs.outputs[0])
    for outputs in runs.outputs:
        assert outputs == expected


@pytest.mark.parametrize("fmi_version", [2, 3])
def test_another_python_active_and_another_folder(fmi_version, fmus, fmus3, c_host, c_host3, other_python, tmp_path):
    """A venv without numpy first on PATH, the host started elsewhere: the FMU runs on the Python it recorded."""
    fmu = (fmus if fmi_version == 2 else fmus3)["SlowPlant"]
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    runs = run_in_c_host(c_host if fmi_version == 2 else c_host3, fmu, tmp_path, runs=3, stop_time=STOP_S,
                         step_size=STEP_S, env=another_python_active(other_python), cwd=elsewhere)
    assert runs.crashes == 0, f"exit codes {runs.exit_codes}:\n{runs.first_failure[-3000:]}"
    expected = fmpy_outputs(fmu, runs.outputs[0])
    assert all(outputs == expected for outputs in runs.outputs)


def test_the_python_an_fmu_starts_runs_one_blas_thread_unless_the_host_says(c_host, tmp_path, monkeypatch):
    """fmus/loader/loader.c: the embedded Python's OpenBLAS pools start one thread, not one per core, unless the
    host's environment sets OPENBLAS_NUM_THREADS (which stays as it is)."""
    fmu = build_probe("BlasProbe", tmp_path, monkeypatch)
    for environment, threads in [(bare_environment(), 1.0), (bare_environment(OPENBLAS_NUM_THREADS="3"), 3.0)]:
        runs = run_in_c_host(c_host, fmu, tmp_path / f"run{threads:g}", runs=1, env=environment)
        assert runs.outputs == [{"blas_threads": threads}], runs.first_failure[-3000:]


@pytest.mark.parametrize("fmi_version", [2, 3])
def test_a_host_calling_from_threads_of_its_own_gets_one_python_thread_state_per_thread(fmi_version, ecos, tmp_path,
                                                                                         monkeypatch):
    """The runtimes' py_safe_run (PySlaveInstance.cpp): ecos steps an FMU from its worker threads, and each
    keeps one Python thread state over the run, where every call made (and mapped) a new one."""
    fmu = build_probe("ThreadStateProbe", tmp_path, monkeypatch, fmi_version)
    runs = run_in_ecos(ecos, fmu, tmp_path, runs=1, stop_time=0.1)  # 200 steps
    assert runs.exit_codes == [0], runs.first_failure[-3000:]
    (stepped_by,) = {values[-1] for name, values in runs.outputs[0].items() if name.endswith("stepped_by")}
    assert 1 <= stepped_by <= 8  # ecos's threads; a new state per call: 200


def test_a_host_making_a_thread_per_step_leaves_at_most_64_python_thread_states(c_host, tmp_path, monkeypatch):
    """py_safe_run keeps the states of 64 threads at most: a host that makes a new thread for every call does
    not pile them up (the C host's NFAL_HOST_THREAD_PER_STEP)."""
    fmu = build_probe("ThreadStateProbe", tmp_path, monkeypatch)
    runs = run_in_c_host(c_host, fmu, tmp_path, runs=1, stop_time=0.15, step_size=STEP_S,
                         env=bare_environment(NFAL_HOST_THREAD_PER_STEP="1"))
    assert runs.exit_codes == [0], runs.first_failure[-3000:]
    assert runs.outputs[0]["stepped_by"] == 300  # a new thread, so a new state, for each step
    assert runs.outputs[0]["held"] == 64 + 2  # the 64 kept, the main thread's and the stepping one's; 301 if every
    # one were kept


def _one_line(runs, *needles: str) -> None:
    """Each run: not killed, and exactly one line naming all ``needles`` in the host's log (stdout) and on stderr."""
    assert runs.signals == 0, runs.exit_codes
    for stdout, stderr in runs.texts:
        for text in (stdout, stderr):
            lines = [line for line in text.splitlines() if all(needle in line for needle in needles)]
            assert len(lines) == 1, f"{needles} in:\n{text}"


@pytest.mark.parametrize("fmi_version", [2, 3])
def test_an_override_naming_a_missing_python_is_one_logged_line_and_an_error(fmi_version, fmus, fmus3, c_host,
                                                                            c_host3, tmp_path):
    missing = str(tmp_path / "no" / "python")
    fmu = (fmus if fmi_version == 2 else fmus3)["SlowPlant"]
    runs = run_in_c_host(c_host if fmi_version == 2 else c_host3, fmu, tmp_path, runs=3,
                         env=bare_environment(**{PYTHON_OVERRIDE_ENV: missing}))
    assert runs.exit_codes == [2] * 3  # the host's "instantiate failed", not a signal
    _one_line(runs, missing, PYTHON_OVERRIDE_ENV)
    logged = [line for line in runs.texts[0][0].splitlines() if line.startswith("log ")]
    assert len(logged) == 1 and logged[0].startswith("log 3 logStatusError: the Python ")


def test_the_override_in_the_fmu_names_another_python(fmus, c_host, other_python, tmp_path):
    """override= in resources/python.cfg: that Python runs the FMU; without numpy, one line says so."""
    fmu = with_config(fmus["SlowPlant"], tmp_path / "SlowPlant.fmu", override=str(other_python))
    runs = run_in_c_host(c_host, fmu, tmp_path / "hosted", runs=1)
    assert runs.exit_codes == [2]
    logged = [line for line in runs.texts[0][0].splitlines() if line.startswith("log ")]
    assert len(logged) == 1 and "'numpy'" in logged[0] and str(other_python) in logged[0], logged


def test_a_python_without_a_shared_libpython_is_one_logged_line(fmus, c_host, tmp_path):
    """A Python whose settings name no libpython (a static build): the line says so and how to check."""
    fake = tmp_path / "static-python"
    fake.write_text("#!/bin/sh\necho executable=$0\necho version=3.11\necho libpython=\necho site=\n")
    fake.chmod(0o755)
    runs = run_in_c_host(c_host, fmus["SlowPlant"], tmp_path, runs=1,
                         env=bare_environment(**{PYTHON_OVERRIDE_ENV: str(fake)}))
    assert runs.exit_codes == [2]
    _one_line(runs, str(fake), "no shared libpython", "Py_ENABLE_SHARED")


def test_an_error_in_a_c_host_is_one_logged_line_and_fmi2error(fmus, c_host, tmp_path):
    """A step that does not divide the Controller's 0.5 ms: fmi2Error with its reason, the host exits cleanly."""
    runs = run_in_c_host(c_host, fmus["Controller"], tmp_path, runs=1, stop_time=0.003, step_size=3e-4)
    assert runs.exit_codes == [3]  # the host's "an FMI call did not return fmi2OK", not a signal
    logged = [line for line in runs.first_failure.splitlines() if line.startswith("log ")]
    assert logged == ["log 3 logStatusError: instance: communication step size = 0.0003 is invalid: must be the sample "
                      "period 0.0005 s divided by a whole number (e.g. 0.0005 s or 0.00025 s) (in doStep at t = 0 s) "
                      "[instance]"]
    assert "fmi2DoStep returned 3" in runs.first_failure


@pytest.fixture(scope="module")
def ecos(tmp_path_factory):
    return host_or_skip(ecos_executable, tmp_path_factory.mktemp("ecos"))


@pytest.mark.parametrize("environment", ["nothing set up", "another Python active"])
def test_the_fig7_archive_runs_in_ecos_without_a_crash(environment, fmus, ecos, other_python, tmp_path):
    """ecos (Jacobi, as libcosim) against our orchestrator's Jacobi run of the same archive."""
    from nfal.apps.build import structure_sources
    from nfal.orchestration import run_structure

    archive = pack(structure_sources() / "fig7_slow.ssd", fmus["SlowPlant"].parent, tmp_path / "fig7_slow.ssp")
    env = bare_environment() if environment == "nothing set up" else another_python_active(other_python)
    runs = run_in_ecos(ecos, archive, tmp_path, runs=3 if environment == "nothing set up" else 2,
                       stop_time=ECOS_STOP_S, env=env)
    assert runs.crashes == 0, f"exit codes {runs.exit_codes}:\n{runs.first_failure[-3000:]}"
    ours = run_structure(archive, stop_time=ECOS_STOP_S, algorithm="jacobi",
                         out_dir=tmp_path / "ours", plot=False)
    voltage = ours["Controller.drive_voltage"]
    for run in runs.outputs:
        # the voltage as the tracker received it at each t_k; ecos writes 6 decimals (rounding <= 5e-7 V)
        theirs = np.array(run["ResonanceTracker::drive_voltage"])
        assert len(theirs) >= len(voltage) - 1  # ecos may stop one step short of the stop time
        np.testing.assert_allclose(theirs, voltage[:len(theirs)], rtol=0, atol=5e-7 * (1 + 1e-9))


def test_an_ecos_that_exits_with_0_and_writes_no_results_is_an_error_saying_what_it_said(tmp_path):
    """Seen twice from ecos.exe under wine beside a loaded machine: exit 0, no CSV (wine's report of a null read in
    ecos.exe). The run is not read as a success, nor fails on the missing file: the error carries the start of what
    ecos printed (how far it got) and its end (wine's crash report), and the whole is kept beside the run."""
    silent = tmp_path / "ecos"
    silent.write_text("#!/bin/sh\necho 'loading Plant'\nseq 2000 >&2\necho 'simulation ended early' >&2\nexit 0\n")
    silent.chmod(0o755)
    with pytest.raises(DataFormatError, match=r"(?s)wrote no fig7_slow\.csv; all it said is in .*ecos_0/ecos\.log; it "
                                              r"began: loading Plant\n1\n.*\[\.\.\.\].*2000\nsimulation ended early"):
        run_in_ecos(silent, tmp_path / "fig7_slow.ssp", tmp_path / "runs", runs=1, stop_time=0.01)
    assert (tmp_path / "runs" / "ecos_0" / "ecos.log").read_text().startswith("loading Plant\n1\n2\n")


def test_a_short_account_from_an_ecos_without_results_is_quoted_once_and_whole(tmp_path):
    silent = tmp_path / "ecos"
    silent.write_text("#!/bin/sh\necho 'loading Plant'\necho 'simulation ended early' >&2\nexit 0\n")
    silent.chmod(0o755)
    with pytest.raises(DataFormatError) as failure:
        run_in_ecos(silent, tmp_path / "fig7_slow.ssp", tmp_path / "runs", runs=1, stop_time=0.01)
    assert str(failure.value).endswith("it said: loading Plant\nsimulation ended early\n")
    assert str(failure.value).count("loading Plant") == 1


@pytest.mark.parametrize("fmi_version", [2, 3])
def test_ecos_with_an_override_naming_a_missing_python_does_not_crash(fmi_version, fmus, fmus3, ecos, tmp_path):
    """ecos shows an FMU's messages only at its debug level and goes on without the instance: the loader's
    line is on stderr as well, and no call on the missing instance crashes ecos."""
    missing = str(tmp_path / "no" / "python")
    fmu = (fmus if fmi_version == 2 else fmus3)["SlowPlant"]
    runs = run_in_ecos(ecos, fmu, tmp_path, runs=2, stop_time=0.005,
                       env=bare_environment(**{PYTHON_OVERRIDE_ENV: missing}))
    assert runs.signals == 0, runs.exit_codes
    for _, stderr in runs.texts:
        naming = [line for line in stderr.splitlines() if missing in line and PYTHON_OVERRIDE_ENV in line]
        assert len(naming) == 1, stderr
