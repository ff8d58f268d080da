"""Our FMUs in non-Python hosts, run many times: no crash (exit code counted), the results FMPy gives.

pythonfmu 0.7.0's runtime crashed such hosts at exit in about 4 runs of 10 (docs/cosimulation.md,
"Crash at exit"); the runtime our FMUs ship (fmus/runtime/) must not. The suite runs each case
RUNS times; ``python bench/host_compat.py`` makes the 100- and 50-run measurement the doc quotes.
"""

from __future__ import annotations

import sys

import numpy as np
import pytest
from fmpy import simulate_fmu

from nfal.errors import HostUnavailableError
from nfal.fmus import build
from nfal.host_check import compile_c_host, ecos_executable, run_in_c_host, run_in_ecos
from nfal.orchestration.ssp_archive import pack

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not sys.platform.startswith("linux"), reason="LD_PRELOAD is the Linux mechanism")]

FIG7_FMUS = ["SlowPlant", "ReynoldsPlant", "Controller", "ResonanceTracker", "SensorChain", "ReferenceGenerator"]
RUNS = 10
STOP_S, STEP_S = 0.01, 5e-4
ECOS_STOP_S = 0.2


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    return build.build_fmus(tmp_path_factory.mktemp("hosts"), FIG7_FMUS)


def host_or_skip(make, folder):
    """The host ``make(folder)`` builds, or a skip naming what this machine lacks (compiler, libtbb12)."""
    try:
        return make(folder)
    except HostUnavailableError as exc:
        pytest.skip(str(exc))


@pytest.fixture(scope="module")
def c_host(tmp_path_factory):
    return host_or_skip(compile_c_host, tmp_path_factory.mktemp("c_host"))


@pytest.mark.parametrize("name", FIG7_FMUS)
def test_every_fmu_runs_in_a_c_host_without_a_crash(name, fmus, c_host, tmp_path):
    """Load, simulate 10 ms, free, dlclose, exit: RUNS times; every output equal to FMPy's, every run."""
    runs = run_in_c_host(c_host, fmus[name], tmp_path, runs=RUNS, stop_time=STOP_S, step_size=STEP_S)
    assert runs.crashes == 0, f"exit codes {runs.exit_codes}:\n{runs.first_failure[-3000:]}"
    reference = simulate_fmu(str(fmus[name]), stop_time=STOP_S, step_size=STEP_S, output_interval=STEP_S,
                             output=list(runs.outputs[0]))
    expected = {output: pytest.approx(float(reference[output][-1]), rel=1e-12, abs=0) for output in runs.outputs[0]}
    for outputs in runs.outputs:
        assert outputs == expected


def test_an_error_in_a_c_host_is_one_logged_line_and_fmi2error(fmus, c_host, tmp_path):
    """A step that does not divide the Controller's 0.5 ms: fmi2Error with its reason, the host exits cleanly."""
    runs = run_in_c_host(c_host, fmus["Controller"], tmp_path, runs=1, stop_time=0.003, step_size=3e-4)
    assert runs.exit_codes == [3]  # the host's "an FMI call did not return fmi2OK", not a signal
    logged = [line for line in runs.first_failure.splitlines() if line.startswith("log ")]
    assert logged == ["log 3 logStatusError: instance: doStep at t = 0 s failed: communication step size = 0.0003 is invalid: "
                      "must be the sample period 0.0005 s divided by a whole number (e.g. 0.0005 s or 0.00025 s) "
                      "[instance]"]
    assert "fmi2DoStep returned 3" in runs.first_failure


@pytest.fixture(scope="module")
def ecos(tmp_path_factory):
    return host_or_skip(ecos_executable, tmp_path_factory.mktemp("ecos"))


def test_the_fig7_archive_runs_in_ecos_without_a_crash(fmus, ecos, tmp_path):
    """ecos (Jacobi, as libcosim) against our orchestrator's Jacobi run of the same archive."""
    from nfal.build import structure_sources
    from nfal.orchestration import run_structure

    archive = pack(structure_sources() / "fig7_slow.ssd", fmus["SlowPlant"].parent, tmp_path / "fig7_slow.ssp")
    runs = run_in_ecos(ecos, archive, tmp_path, runs=RUNS // 2, stop_time=ECOS_STOP_S)
    assert runs.crashes == 0, f"exit codes {runs.exit_codes}:\n{runs.first_failure[-3000:]}"
    ours = run_structure(archive, stop_time=ECOS_STOP_S, algorithm="jacobi",
                         out_dir=tmp_path / "ours", plot=False)
    voltage = ours["Controller.drive_voltage"]
    for run in runs.outputs:
        # the voltage as the tracker received it at each t_k; ecos writes 6 decimals (rounding <= 5e-7 V)
        theirs = np.array(run["ResonanceTracker::drive_voltage"])
        assert len(theirs) >= len(voltage) - 1  # ecos may stop one step short of the stop time
        np.testing.assert_allclose(theirs, voltage[:len(theirs)], rtol=0, atol=5e-7 * (1 + 1e-9))
