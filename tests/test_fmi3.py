"""FMI 3.0 variants of the FMUs (``nfal build --fmi 3``, fmus/fmi3.py): valid, and equal to FMI 2.0 in FMPy.

Each FMU is the same slave (fmus/<slave>.py) packed with pythonfmu3's FMI 3.0 wrapper; FMPy runs both
builds with the same start values and inputs, and the outputs must agree exactly (the same Python code
computes them; only the C wrapper and the FMI calls differ). In the non-Python hosts (the ``ecos`` command line and
fmus/hosts/fmi3_host.c) every run must also exit with 0: the patched runtime of fmus/runtime3/ (issue 15).
"""

from __future__ import annotations

import json
import subprocess
import zipfile
import sys
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, instantiate_fmu, read_model_description, simulate_fmu
from fmpy.validation import validate_fmu

from nfal.apps.build import build_all
from nfal.cli import main
from nfal.fmus.build import FMU_SCRIPTS, build_fmus
from nfal.orchestration import compiled_exchange, run_structure

from helpers.fmu_instance import runtime_slave
from helpers.probe_fmus import build_probe

pytestmark = [pytest.mark.slow,  # the FMI 3.0 FMUs built, run in FMPy, ecos and a C host
              pytest.mark.xdist_group("fmi3")]  # one worker: its module fixtures built once

pytest.importorskip("pythonfmu3")

#: Per FMU: start values (inputs held constant) and the run's stop time [s] (step 0.5 ms, the Controller's period).
SCENARIOS = {
    "SlowPlant": ({"excitation_amplitude": 4e-6, "initial_height": 80e-6}, 0.05),
    "ReynoldsPlant": ({"excitation_amplitude": 4e-6, "shape": "piston"}, 0.002),
    "Controller": ({"reference": 100e-6, "measured_height": 60e-6}, 0.05),
    "ResonanceTracker": ({"drive_voltage": 50.0, "resonance_shift": 20.0}, 0.05),
    "SensorChain": ({"true_height": 80e-6, "noise_peak": 2e-6}, 0.05),
    "ReferenceGenerator": ({"lead": 0.01, "hold": 0.02}, 0.05),
}
STEP = 5e-4
ECOS_OUTPUTS = Path(__file__).parent / "hosts" / "ecos_outputs.py"


@pytest.fixture(scope="module")
def builds(tmp_path_factory):
    """{2: {name: .fmu}, 3: {name: .fmu}}: every FMU built for each FMI version."""
    root = tmp_path_factory.mktemp("fmi_versions")
    return {version: build_fmus(root / f"fmi{version}", fmi_version=version) for version in (2, 3)}


def _fmpy(fmu: Path, name: str):
    start_values, stop = SCENARIOS[name]
    return simulate_fmu(str(fmu), stop_time=stop, step_size=STEP, output_interval=STEP, fmi_type="CoSimulation",
                        start_values=start_values)


@pytest.mark.parametrize("name", sorted(FMU_SCRIPTS))
def test_fmi3_fmu_is_valid_and_declares_what_fmi2_does(builds, name):
    assert validate_fmu(str(builds[3][name])) == []
    fmi2, fmi3 = (read_model_description(str(builds[v][name])) for v in (2, 3))
    assert fmi3.fmiVersion == "3.0" and fmi3.coSimulation.modelIdentifier == name
    declared = {v.name: (v.causality, v.unit, v.start) for v in fmi2.modelVariables}
    assert {v.name: (v.causality, v.unit, v.start) for v in fmi3.modelVariables if v.name != "time"} == declared
    assert [v.causality for v in fmi3.modelVariables if v.name == "time"] == ["independent"]
    dependencies = {u.variable.name: sorted(d.name for d in u.dependencies or ()) for u in fmi2.outputs}
    assert {u.variable.name: sorted(d.name for d in u.dependencies or ()) for u in fmi3.outputs} == dependencies
    assert fmi3.coSimulation.canGetAndSetFMUstate == fmi2.coSimulation.canGetAndSetFMUstate == (name != "HardwareProxy")


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_fmi3_results_equal_fmi2_in_fmpy(builds, name):
    runs = [_fmpy(builds[v][name], name) for v in (2, 3)]
    assert runs[0].dtype.names == runs[1].dtype.names and len(runs[0]) == round(SCENARIOS[name][1] / STEP) + 1
    for column in runs[0].dtype.names:
        np.testing.assert_array_equal(runs[1][column], runs[0][column], err_msg=f"{name}.{column}")
    moving = [c for c in runs[0].dtype.names if c != "time" and np.ptp(runs[0][c].astype(float)) > 0]
    assert moving, f"{name}: nothing changes in the scenario, so the comparison says little"


@pytest.mark.parametrize("stop", [0.01, None], ids=["stop declared", "no stop"])
def test_the_slave_gets_the_start_and_stop_time_the_host_declares_as_in_fmi2(stop, tmp_path, monkeypatch):
    """fmi3EnterInitializationMode's start and stop time reach the slave's setup_experiment (the runtime's
    SetupExperiment), as fmi2SetupExperiment's do: pythonfmu3's runtime dropped them."""
    for version in (2, 3):
        fmu = build_probe("TimesProbe", tmp_path, monkeypatch, version)
        model = read_model_description(str(fmu))
        values = {v.name: v.valueReference for v in model.modelVariables}
        instance = instantiate_fmu(extract(str(fmu), str(fmu.parent / "extracted")), model, fmi_type="CoSimulation")
        try:
            if version == 2:
                instance.setupExperiment(startTime=0.25, stopTime=stop)
                instance.enterInitializationMode()
            else:
                instance.enterInitializationMode(startTime=0.25, stopTime=stop)
            instance.exitInitializationMode()
            read = instance.getReal if version == 2 else instance.getFloat64
            declared = read([values["declared_start"], values["declared_stop"]])
        finally:
            instance.terminate()
            instance.freeInstance()
        assert declared == [0.25, -1.0 if stop is None else stop], f"FMI {version}.0"


@pytest.mark.parametrize("name", ["Controller", "SensorChain"])
def test_fmi3_samples_where_fmi2_does_from_a_start_off_the_sample_grid(builds, name):
    """A start time half a period off the 0.5 ms grid: both builds sample from the host's start time (the FMI 3.0
    build sampled from t = 0, so never, while the runtime dropped the start time)."""
    start_values, stop = SCENARIOS[name]
    runs = [simulate_fmu(str(builds[v][name]), start_time=STEP / 2, stop_time=STEP / 2 + stop, step_size=STEP,
                         output_interval=STEP, fmi_type="CoSimulation", start_values=start_values) for v in (2, 3)]
    for column in runs[0].dtype.names:
        np.testing.assert_array_equal(runs[1][column], runs[0][column], err_msg=f"{name}.{column}")


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_fmi3_results_in_ecos_equal_fmi2_in_fmpy(builds, name, tmp_path):
    """A second FMI 3.0 host, not written in Python: ecos (ecospy 0.7.2), in a subprocess."""
    pytest.importorskip("ecospy")
    from nfal.orchestration.libcosim import preload_environment

    start_values, stop = SCENARIOS[name]
    out = tmp_path / "ecos.npz"
    subprocess.run([sys.executable, str(ECOS_OUTPUTS), str(builds[3][name]), json.dumps(start_values), str(stop),
                    str(STEP), str(out)], env=preload_environment(), capture_output=True, timeout=600)
    assert out.is_file(), f"ecos did not run {name}"
    ecos, fmpy_fmi2 = np.load(out), _fmpy(builds[2][name], name)
    assert set(ecos.files) <= set(fmpy_fmi2.dtype.names) and ecos.files
    for column in ecos.files:  # the hosts' communication points may differ in the last bit (k h vs. a sum of h)
        np.testing.assert_allclose(ecos[column], fmpy_fmi2[column], rtol=1e-12, atol=0, err_msg=f"{name}.{column}")


#: Runs of each FMU in the ecos command line and in the C host: pythonfmu3's stock runtime crashed at exit in 10 of
#: 15 ecos runs and 31 of 50 C-host runs, so 10 runs of it would all exit cleanly with a chance below 1e-4.
EXIT_RUNS = 2


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_fmi3_fmu_exits_cleanly_from_a_non_python_host(builds, name, tmp_path):
    """The ``ecos`` command line starts Python through the FMU (libpython preloaded): every run must exit with 0
    (the runtime of fmus/runtime3/ never finalises the interpreter) after simulating to the stop time."""
    from nfal.errors import HostUnavailableError
    from nfal.apps.host_check import ecos_executable, run_in_ecos

    try:
        ecos = ecos_executable(tmp_path / "bin")
    except HostUnavailableError as exc:
        pytest.skip(str(exc))
    stop = 0.01
    runs = run_in_ecos(ecos, builds[3][name], tmp_path, runs=EXIT_RUNS, stop_time=stop, step_size=STEP)
    assert runs.exit_codes == [0] * EXIT_RUNS, runs.first_failure[-3000:]
    for run in runs.outputs:
        assert run["time"][-1] == pytest.approx(stop - STEP, rel=1e-9) and len(run["time"]) == round(stop / STEP)


@pytest.fixture(scope="module")
def c_host(tmp_path_factory):
    """fmus/hosts/fmi3_host.c, compiled (or a skip without a C compiler)."""
    from nfal.errors import HostUnavailableError
    from nfal.apps.host_check import compile_c_host

    try:
        return compile_c_host(tmp_path_factory.mktemp("c_host"), fmi_version=3)
    except HostUnavailableError as exc:
        pytest.skip(str(exc))


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_fmi3_fmu_in_a_c_host_exits_cleanly_with_fmpys_results(builds, c_host, name, tmp_path):
    """Load, simulate 10 ms from the start values, free, dlclose, exit: every run exits with 0 and its Float64
    outputs equal those of the FMI 2.0 build in FMPy."""
    from nfal.apps.host_check import run_in_c_host

    runs = run_in_c_host(c_host, builds[3][name], tmp_path, runs=EXIT_RUNS, stop_time=0.01, step_size=STEP)
    assert runs.crashes == 0, f"exit codes {runs.exit_codes}:\n{runs.first_failure[-3000:]}"
    reference = simulate_fmu(str(builds[2][name]), stop_time=0.01, step_size=STEP, output_interval=STEP)
    expected = {output: pytest.approx(float(reference[output][-1]), rel=1e-12, abs=0) for output in runs.outputs[0]}
    assert runs.outputs == [expected] * EXIT_RUNS and expected


def test_fmi3_error_in_a_c_host_is_one_logged_line_and_fmi3error(builds, c_host, tmp_path):
    """A step that does not divide the Controller's 0.5 ms: fmi3Error with its reason, the host exits cleanly."""
    from nfal.apps.host_check import run_in_c_host

    runs = run_in_c_host(c_host, builds[3]["Controller"], tmp_path, runs=1, stop_time=0.003, step_size=3e-4)
    assert runs.exit_codes == [3]  # the host's "an FMI call did not return fmi3OK", not a signal
    logged = [line for line in runs.first_failure.splitlines() if line.startswith("log ")]
    assert logged == ["log 3 logStatusError: instance: communication step size = 0.0003 is invalid: must be the sample "
                      "period 0.0005 s divided by a whole number (e.g. 0.0005 s or 0.00025 s) (in doStep at t = 0 s) "
                      "[instance]"]
    assert "fmi3DoStep returned 3" in runs.first_failure and "version=3.0" in runs.first_failure


FAILING_TWICE_THEN_RUNNING = """
import json
import sys
from fmpy import simulate_fmu
from fmpy.fmi1 import FMICallException
messages = []
for _ in range(2):
    try:
        simulate_fmu(sys.argv[1], stop_time=0.01, step_size=5e-4, start_values={"mass": -1.0},
                     logger=lambda *args: messages.append(args[-1].decode()))
    except FMICallException as exc:
        print(exc.function, exc.status)
print(json.dumps(messages))
print(simulate_fmu(sys.argv[1], stop_time=0.01, step_size=5e-4)["height"][-1])
"""


def test_fmi3_bad_parameter_is_one_logged_error_not_a_crash(builds):
    """The patched runtime (fmus/runtime3/): fmi3Error (3) and one logged line per failure, as in FMI 2.0."""
    done = subprocess.run([sys.executable, "-c", FAILING_TWICE_THEN_RUNNING, str(builds[3]["SlowPlant"])],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    lines = done.stdout.splitlines()
    assert lines[:2] == ["fmi3ExitInitializationMode 3"] * 2  # fmi3Error, not pythonfmu3's fmi3Fatal
    assert json.loads(lines[2]) == ["SlowPlant: mass = -1.0 is invalid: must be a finite number > 0 "
                                    "(in exit_initialization_mode, the set-up from the parameters)"] * 2
    assert 0 < float(lines[-1]) < 1e-3  # the same process still runs the FMU


def _sensor_readings(fmu: Path, folder: Path, heights, analog_cutoff: float) -> tuple[list[float], list[str]]:
    """A SensorChain run in this process: each step sets true_height, steps, reads measured_height twice; the
    readings, and the calls that reached the slave's Python getters and setters of Reals (the value cache's)."""
    description = read_model_description(str(fmu))
    refs = {v.name: v.valueReference for v in description.modelVariables}
    instance = instantiate_fmu(extract(str(fmu), str(folder)), description, fmi_type="CoSimulation")
    fmi3 = description.fmiVersion.startswith("3")
    get, set_ = (instance.getFloat64, instance.setFloat64) if fmi3 else (instance.getReal, instance.setReal)
    try:
        set_([refs["analog_cutoff"]], [analog_cutoff])
        if fmi3:
            instance.enterInitializationMode(startTime=0.0)
        else:
            instance.setupExperiment(startTime=0.0)
            instance.enterInitializationMode()
        instance.exitInitializationMode()
        slave = runtime_slave("SensorChain", instance.instanceName)
        calls = []
        for method in ("get_real", "set_real"):
            original = getattr(slave, method)
            setattr(slave, method, lambda *args, _f=original, _m=method: (calls.append(_m), _f(*args))[1])
        readings = []
        for k, height in enumerate(heights):
            set_([refs["true_height"]], [height])
            instance.doStep(k * STEP, STEP)
            readings += get([refs["measured_height"]]) + get([refs["measured_height"]])
        return readings, calls
    finally:
        instance.terminate()
        instance.freeInstance()


@pytest.mark.parametrize("analog_cutoff, calls", [(0.0, ["get_real"]), (2000.0, [])])
def test_both_runtimes_answer_from_the_value_cache_alike(builds, tmp_path, analog_cutoff, calls):
    """fmus/value_cache/ in both runtimes: the set of an input never reaches the slave; without the analog filter
    the measurement is computed from true_height once after each step (its first read); behind the filter it is the
    state's, written as the step ends, and no read reaches the slave. Both builds read the same values."""
    heights = [80e-6 + 1e-7 * k for k in range(40)]
    (readings2, calls2), (readings3, calls3) = (
        _sensor_readings(builds[version]["SensorChain"], tmp_path / f"fmi{version}", heights, analog_cutoff)
        for version in (2, 3))
    assert readings3 == readings2 and len(set(readings2)) > 2
    assert calls2 == calls3 == calls * len(heights)


def test_nfal_build_fmi3_builds_the_fmus_and_packs_the_structures(capsys, tmp_path):
    assert main(["build", "--fmi", "3", "--out", str(tmp_path), "--json"]) == 0
    archives = json.loads(capsys.readouterr().out)
    assert sorted(p.name for p in (tmp_path / "fmi3").glob("*.fmu")) == sorted(f"{n}.fmu" for n in FMU_SCRIPTS)
    assert archives["fig7_slow"] == str(tmp_path / "fmi3" / "fig7_slow.ssp") and not list(tmp_path.glob("*.ssp"))
    with zipfile.ZipFile(archives["fig7_slow"]) as packed:
        with packed.open("resources/SlowPlant.fmu") as fmu, zipfile.ZipFile(fmu) as inner:
            assert b'fmiVersion="3.0"' in inner.read("modelDescription.xml")


def test_the_master_steps_fmi3_fmus_in_c_as_in_python(tmp_path, monkeypatch):
    """fig7_slow of FMI 3.0 FMUs (fmi3DoStep's flags, fmi3GetFloat64 and fmi3GetBoolean's nValues): the master's
    compiled step gives results.csv byte for byte as its Python does."""
    archive = build_all(tmp_path / "build", fmi_version=3, structures=("fig7_slow",))["fig7_slow"]
    runs = {}
    for switch in ("on", "off"):
        monkeypatch.setenv(compiled_exchange.SWITCH, switch)
        compiled_exchange.library.cache_clear()
        runs[switch] = run_structure(archive, stop_time=0.1, step_size=STEP, out_dir=tmp_path / switch, plot=False,
                                     progress=False)
    compiled_exchange.library.cache_clear()
    assert [run.summary["exchange_engine"] for run in runs.values()] == ["C", "Python"]
    assert (tmp_path / "on" / "results.csv").read_bytes() == (tmp_path / "off" / "results.csv").read_bytes()
