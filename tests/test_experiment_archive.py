"""The experiment travels with the archive (issue 24): the ReferenceGenerator FMU, the SSD's stop time, FMI 3.0 end
to end.

* The ReferenceGenerator (fmus/reference_generator.py over models/reference.py) gives the value the master's
  staircase gives at every communication point, so ``nfal run`` with it equals ``nfal run --reference staircase``
  (which replaces its connection) exactly; any host (ecos) runs the same experiment.
* The SSD's DefaultExperiment stopTime governs; the staircase's length is the stop time only where the SSD has none,
  and the run says where the two differ.
* ``nfal build --fmi 3`` packs the structures with the FMI 3.0 FMUs; ``nfal run`` runs them, and mixes of FMI 2.0
  and FMI 3.0, with the FMI 2.0 run's results.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import simulate_fmu
from fmpy.validation import validate_fmu
from nfal.fmus.reference_generator import PARAMETERS, ReferenceGenerator, reference_of
from nfal.models.reference import Staircase
from nfal.models.reference import StepSequence, staircase_of
from nfal.orchestration import read_results, read_ssp, resolve
from nfal.orchestration.signals import as_signal

from nfal.cli import main
from nfal.apps.structure_run import _stop_time
from nfal.errors import DataFormatError, InvalidParameterError
from nfal.apps.fig7 import DEFAULT_STAIRCASES, generated_reference

pytestmark = [pytest.mark.slow,  # whole experiments in FMPy and ecos
              pytest.mark.xdist_group("experiment_archive")]  # one worker: its module fixtures built once

STEP = 5e-4
ECOS_SSP_OUTPUTS = Path(__file__).parent / "hosts" / "ecos_ssp_outputs.py"


# --- the model and the slave as Python objects ------------------------------------------------------------------

@pytest.mark.parametrize("staircase", [Staircase(), DEFAULT_STAIRCASES["fig7_reynolds"], Staircase(lead_s=1.0),
                                       Staircase((60e-6, 90e-6), 0.3, 0.2)])
def test_step_sequence_gives_the_masters_staircase_at_every_communication_point(staircase):
    sequence, signal = StepSequence.from_staircase(staircase), as_signal(staircase)
    times = np.arange(round(staircase.duration_s / STEP) + 1) * STEP
    assert [sequence(t) for t in times] == [signal(t) for t in times]
    # the FMU's own clock: t + dt summed step by step, which may differ from k * dt in the last bits
    summed = np.cumsum(np.full(times.size - 1, STEP))
    assert [sequence(t) for t in summed] == [signal(t) for t in times[1:]]


@pytest.mark.parametrize("text", [
    "time_s,reference_m\n0,60e-6\n0.2,80e-6\n0.5,70e-6\n",
    "0,60e-6;0.2,80e-6;0.5,70e-6",
    "time_s,reference_m 0,60e-6 0.2,80e-6 0.5,70e-6",  # newlines as an SSV attribute turns them: spaces
    "# a comment\n0, 60e-6\n\n0.2,80e-6;0.5,70e-6",
])
def test_a_table_is_read_in_every_row_layout(text):
    sequence = StepSequence.from_table(text)
    assert sequence.times_s == (0.0, 0.2, 0.5) and sequence.levels_m == (60e-6, 80e-6, 70e-6)
    assert [sequence(t) for t in (0.0, 0.1999, 0.2, 0.4, 0.5, 9.0)] == [60e-6, 60e-6, 80e-6, 80e-6, 70e-6, 70e-6]


@pytest.mark.parametrize("text, error, named", [
    ("0,60e-6;0,80e-6", InvalidParameterError, "change time 2"),
    ("0,60e-6;0.1,-80e-6", InvalidParameterError, "level 2"),
    ("0,60e-6;0.1,nan", InvalidParameterError, "level 2"),
    ("0,60e-6;0.1,80e-6,3", DataFormatError, "row 2"),
    ("0,60e-6;zero,80e-6", DataFormatError, "row 2"),
    ("time_s,reference_m", DataFormatError, "no rows"),
])
def test_a_bad_table_is_refused_by_name(text, error, named):
    with pytest.raises(error, match=named):
        StepSequence.from_table(text)


def test_explicit_steps_and_their_staircase():
    steps = StepSequence.from_text("0 0.1 0.7", "60e-6, 100e-6, 140e-6")
    assert steps(0.5) == 100e-6 and steps.duration_s == 0.7
    assert staircase_of(StepSequence.from_staircase(Staircase())).step_times_s == \
        pytest.approx(Staircase().step_times_s)
    assert staircase_of(StepSequence.from_text("0 0.1 0.2 0.7", "1e-4 2e-4 1e-4 2e-4")) is None  # unequal holds
    with pytest.raises(InvalidParameterError, match="2 times, 3 levels"):
        StepSequence.from_text("0 0.1", "1e-4 2e-4 1e-4")


def _slave(**parameters) -> ReferenceGenerator:
    slave = ReferenceGenerator(instance_name="reference", resources=parameters.pop("resources", None))
    for name, value in parameters.items():
        setattr(slave, name, value)
    slave.setup_experiment(0.0)
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    return slave


def _run(slave: ReferenceGenerator, stop_s: float) -> list[float]:
    values = [slave._reference()]
    while slave.time < stop_s - 1e-9:
        slave.do_step(slave.time, STEP)
        values.append(slave._reference())
    return values


def test_the_slave_gives_the_papers_staircase_by_default():
    assert _run(_slave(), 3.7) == [as_signal(Staircase())(k * STEP) for k in range(7401)]
    assert reference_of({}) == Staircase()
    assert PARAMETERS["levels"] == "6e-05 0.0001 0.00014 0.00018 0.00014 0.0001 6e-05"


def test_the_slave_takes_steps_a_table_and_a_file_in_its_resources(tmp_path):
    assert _run(_slave(times="0 0.001", levels="70e-6 90e-6"), 0.002) == [70e-6, 70e-6, 90e-6, 90e-6, 90e-6]
    assert _run(_slave(table="0,70e-6;0.0015,50e-6"), 0.002) == [70e-6, 70e-6, 70e-6, 50e-6, 50e-6]
    (tmp_path / "mine.csv").write_text("time_s,reference_m\n0,80e-6\n0.001,85e-6\n")
    assert _run(_slave(table="mine.csv", resources=str(tmp_path)), 0.001) == [80e-6, 80e-6, 85e-6]


@pytest.mark.parametrize("parameters, named", [
    ({"levels": "60e-6"}, "at least two levels"),
    ({"levels": "60 um 100 um"}, "levels"),
    ({"levels": "60 100"}, r"ReferenceGenerator levels = \(60.0, 100.0\) is invalid: must be clearances within "
                           r"1.0–1000.0 µm \(did you give µm or mm as m\?\)"),
    ({"table": "0,60;0.1,80"}, r"ReferenceGenerator levels = \(60.0, 80.0\) is invalid"),
    ({"hold": -0.6}, "hold_s"),
    ({"times": "0 0.1", "levels": "60e-6"}, "2 times, 1 levels"),
    ({"table": "../secrets.csv"}, "resources folder"),
])
def test_bad_parameters_fail_initialisation_by_name(tmp_path, parameters, named):
    with pytest.raises(ValueError, match=named):
        _slave(resources=str(tmp_path), **parameters)


def test_stop_time_the_ssd_governs_and_the_run_says_where_the_reference_differs():
    assert _stop_time(None, 3.7, Staircase()) == (3.7, None)
    stop, note = _stop_time(None, 0.25, Staircase())
    assert stop == 0.25 and "stopTime (0.25 s) governs, before the reference's end" in note and "3.7 s" in note
    assert _stop_time(None, None, Staircase()) == (Staircase().duration_s, None)  # the SSD says nothing: its length
    assert _stop_time(0.5, 3.7, Staircase()) == (0.5, None)  # asked for
    assert "after the reference's last change" in _stop_time(None, 5.0, Staircase())[1]


# --- the FMU, the structures and nfal run ------------------------------------------------------------------------

@pytest.fixture(scope="module")
def generator_fmu(fig7_archives) -> Path:
    return fig7_archives["fig7_slow"].parent / "ReferenceGenerator.fmu"


def test_the_fmu_is_valid_and_runs_a_table_in_fmpy(generator_fmu):
    assert validate_fmu(str(generator_fmu)) == []
    result = simulate_fmu(str(generator_fmu), stop_time=0.003, step_size=STEP, output_interval=STEP,
                          start_values={"table": "time_s,reference_m 0,70e-6 0.002,90e-6"})
    assert result["reference"].tolist() == [70e-6] * 4 + [90e-6] * 3


@pytest.mark.parametrize("structure, expected", [
    ("fig7_slow", Staircase()), ("fig7_reynolds", DEFAULT_STAIRCASES["fig7_reynolds"]),
])
def test_each_structure_carries_the_staircase_nfal_run_used_to_feed(fig7_archives, structure, expected):
    """fig7_hil carries none: nfal run drives its reference (a paced run has no time for one more FMU)."""
    with read_ssp(fig7_archives[structure]) as read:
        generated = generated_reference(resolve(read))
        stop = read.default_experiment.stop_time
    assert generated.source == "ReferenceGenerator.reference" and generated.reference == expected
    assert stop == pytest.approx(expected.duration_s)
    with read_ssp(fig7_archives[structure]) as read:  # a --param reaches the generator as the FMU would see it
        generated = generated_reference(resolve(read, {"ReferenceGenerator.levels": "70e-6 90e-6"}))
    assert generated.reference == Staircase((70e-6, 90e-6), lead_s=expected.lead_s)


def test_a_bad_generator_parameter_on_the_command_line_is_refused_by_name(fig7_archives, tmp_path, capsys):
    archive = str(fig7_archives["fig7_slow"])
    assert main(["run", archive, "--param", "ReferenceGenerator.levels=60e-6", "--out", str(tmp_path / "a")]) == 2
    # a number, read as its text
    assert "levels_m = (6e-05,) is invalid: must be at least two levels" in capsys.readouterr().err
    assert main(["run", archive, "--param", "ReferenceGenerator.table=0,60e-6;0.1,-1",
                 "--out", str(tmp_path / "b")]) == 2
    assert "level 2 = -1.0 is invalid" in capsys.readouterr().err


def _table(folder: Path):
    return read_results(folder / "results.csv")


@pytest.mark.slow
def test_nfal_run_with_the_generator_equals_the_masters_staircase(fig7_archives, tmp_path, capsys):
    archive = str(fig7_archives["fig7_slow"])
    assert main(["run", "--no-plot", archive, "--stop-time", "0.8", "--out", str(tmp_path / "fmu")]) == 0
    assert main(["run", "--no-plot", archive, "--stop-time", "0.8", "--reference", "staircase",
                 "--out", str(tmp_path / "master")]) == 0
    fmu, master = _table(tmp_path / "fmu"), _table(tmp_path / "master")
    # the master's input replaced the link
    assert "Controller.reference" not in fmu and "Controller.reference" in master
    np.testing.assert_array_equal(fmu["ReferenceGenerator.reference"], master["Controller.reference"])
    for column in fmu.names:
        np.testing.assert_array_equal(fmu[column], master[column], err_msg=column)
    summaries = [json.loads((tmp_path / run / "summary.json").read_text()) for run in ("fmu", "master")]
    assert summaries[0]["experiment"]["reference"] == "ReferenceGenerator.reference"
    assert summaries[0]["metrics"]["steps"] == summaries[1]["metrics"]["steps"]
    assert len(summaries[0]["metrics"]["steps"]) == 1


def _edited_structure(archive: Path, folder: Path, old: str, new: str) -> Path:
    with zipfile.ZipFile(archive) as packed:
        packed.extractall(folder)
    ssd = folder / "SystemStructure.ssd"
    text = ssd.read_text(encoding="utf-8")
    assert old in text
    ssd.write_text(text.replace(old, new), encoding="utf-8")
    return ssd


def test_an_edited_stop_time_runs_as_edited_and_says_so(fig7_archives, tmp_path, capsys):
    ssd = _edited_structure(fig7_archives["fig7_slow"], tmp_path / "edited", 'stopTime="3.7"', 'stopTime="0.25"')
    assert main(["run", "--no-plot", str(ssd), "--out", str(tmp_path / "run"), "--json"]) == 0
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    assert summary["end_time_s"] == pytest.approx(0.25) and summary["steps_completed"] == 500
    assert ("DefaultExperiment stopTime (0.25 s) governs, before the reference's end: the reference lasts 3.7 s"
            in captured.err)
    assert summary["experiment"]["stop_time_note"] in captured.err
    assert summary["metrics"]["steps"] is None  # the IAE, and why no step table:
    assert summary["metrics"]["no_steps"] == "no step of the staircase completes its hold by 0.25 s"
    assert _table(tmp_path / "run").time[-1] == pytest.approx(0.25)


def test_an_edited_reference_in_the_ssd_drives_the_run(fig7_archives, tmp_path, capsys):
    """The generator's parameters as a user edits them into the SSD: nfal run runs that experiment (its metrics too)."""
    binding = ('<ssd:ParameterBindings><ssd:ParameterBinding><ssd:ParameterValues><ssv:ParameterSet version="1.0" '
               'name="mine"><ssv:Parameters><ssv:Parameter name="levels"><ssv:String value="60e-6 70e-6"/>'
               '</ssv:Parameter><ssv:Parameter name="hold"><ssv:Real value="0.1"/></ssv:Parameter></ssv:Parameters>'
               '</ssv:ParameterSet></ssd:ParameterValues></ssd:ParameterBinding></ssd:ParameterBindings>')
    connectors = ('<ssd:Connector name="reference" kind="output"><ssc:Real unit="m"/></ssd:Connector>\n'
                  '        </ssd:Connectors>')
    ssd = _edited_structure(fig7_archives["fig7_slow"], tmp_path / "edited", connectors, connectors + binding)
    assert main(["run", "--no-plot", str(ssd), "--out", str(tmp_path / "run"), "--json"]) == 0
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    assert "stopTime (3.7 s) governs, after the reference's last change: the reference lasts 0.2 s" in captured.err
    reference = _table(tmp_path / "run")["ReferenceGenerator.reference"]
    assert set(reference[:200]) == {60e-6} and set(reference[200:]) == {70e-6}
    assert len(summary["metrics"]["steps"]) == 1  # the one step of the edited staircase, 60 -> 70 um


# --- FMI 3.0 end to end ------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def fmi3_archives(tmp_path_factory):
    """``nfal build --fmi 3``'s archives: {structure: .ssp}."""
    from nfal.apps.build import build_all

    return build_all(tmp_path_factory.mktemp("fmi3_build") / "fmi3", fmi_version=3)


@pytest.mark.slow
def test_the_fmi3_archive_equals_the_fmi2_run(fig7_archives, fmi3_archives, tmp_path):
    for version, archive in ((2, fig7_archives["fig7_slow"]), (3, fmi3_archives["fig7_slow"])):
        assert main(["run", "--no-plot", str(archive), "--stop-time", "0.8",
                     "--out", str(tmp_path / f"fmi{version}")]) == 0
    fmi2, fmi3 = _table(tmp_path / "fmi2"), _table(tmp_path / "fmi3")
    assert fmi2.names == fmi3.names
    np.testing.assert_allclose(fmi3["Plant.height"], fmi2["Plant.height"], rtol=0, atol=1e-12)
    for column in fmi2.names:  # in fact equal: the same Python computes them
        np.testing.assert_array_equal(fmi3[column], fmi2[column], err_msg=column)


@pytest.mark.slow
def test_a_structure_mixing_fmi2_and_fmi3_runs_as_either(fig7_archives, fmi3_archives, tmp_path):
    from nfal.orchestration.ssp_archive import pack

    from nfal.apps.build import structure_sources

    mixed = tmp_path / "mixed"
    mixed.mkdir()
    for name in ("SlowPlant", "Controller", "ResonanceTracker", "SensorChain", "ReferenceGenerator"):
        fmi3 = name in ("SlowPlant", "SensorChain", "ReferenceGenerator")
        source = (fmi3_archives if fmi3 else fig7_archives)["fig7_slow"].parent / f"{name}.fmu"
        shutil.copy2(source, mixed / f"{name}.fmu")
    archive = pack(structure_sources() / "fig7_slow.ssd", mixed, tmp_path / "mixed.ssp")
    for algorithm in ("causal", "jacobi"):
        assert main(["run", "--no-plot", str(archive), "--stop-time", "0.3", "--algorithm", algorithm,
                     "--out", str(tmp_path / f"mixed-{algorithm}")]) == 0
        assert main(["run", "--no-plot", str(fig7_archives["fig7_slow"]), "--stop-time", "0.3", "--algorithm",
                     algorithm, "--out", str(tmp_path / f"fmi2-{algorithm}")]) == 0
        ours, theirs = _table(tmp_path / f"mixed-{algorithm}"), _table(tmp_path / f"fmi2-{algorithm}")
        for column in theirs.names:
            np.testing.assert_array_equal(ours[column], theirs[column], err_msg=f"{algorithm}: {column}")


# --- ecos runs the experiment in the archive ---------------------------------------------------------------------

@pytest.fixture(scope="module")
def ecos(tmp_path_factory):
    from nfal.errors import HostUnavailableError
    from nfal.apps.host_check import ecos_executable

    try:
        return ecos_executable(tmp_path_factory.mktemp("ecos_bin"))
    except HostUnavailableError as exc:
        pytest.skip(str(exc))


@pytest.fixture(scope="module")
def jacobi_run(fig7_archives, tmp_path_factory):
    """nfal run of fig7_slow's whole staircase with ecos's algorithm (libcosim's fixed-step Jacobi)."""
    out = tmp_path_factory.mktemp("jacobi")
    assert main(["run", "--no-plot", str(fig7_archives["fig7_slow"]), "--algorithm", "jacobi", "--out", str(out),
                 "--overwrite"]) == 0
    return _table(out)


@pytest.mark.slow
@pytest.mark.parametrize("fmi", [2, 3])
def test_the_ecos_command_line_runs_the_whole_staircase(fig7_archives, fmi3_archives, ecos, jacobi_run, tmp_path, fmi):
    """ecos with nothing but the archive: the staircase of Figs. 9-10, the heights of nfal run to ecos's 6 decimals.
    FMI 3.0's archive over its first steps (1.5 s, 3000 steps): the same Python computes both versions'
    values (test_the_fmi3_archive_equals_the_fmi2_run), and the whole staircase in ecos took 20 s."""
    from nfal.apps.host_check import run_in_ecos

    archive = (fig7_archives if fmi == 2 else fmi3_archives)["fig7_slow"]
    stop_time = 3.7 if fmi == 2 else 1.5
    runs = run_in_ecos(ecos, archive, tmp_path, runs=1, stop_time=stop_time)
    assert runs.crashes == 0 and runs.exit_codes == [0], runs.first_failure[-3000:]
    theirs = runs.outputs[0]
    rows = len(theirs["time"])
    assert rows >= round(stop_time / STEP)  # ecos may stop one step short of the stop time
    np.testing.assert_allclose(theirs["time"], jacobi_run.time[:rows], rtol=0, atol=1e-9)
    levels = set(theirs["ReferenceGenerator::reference"])
    if fmi == 2:
        assert levels == set(Staircase().levels_m)
    else:
        assert len(levels) >= 3  # the first steps: each value held to nfal run's below
    for ecos_name, ours in (("Plant::height", "Plant.height"),
                            ("SensorChain::measured_height", "SensorChain.measured_height"),
                            ("ReferenceGenerator::reference", "ReferenceGenerator.reference")):
        np.testing.assert_allclose(theirs[ecos_name], jacobi_run[ours][:rows], rtol=0, atol=5e-7 * (1 + 1e-9),
                                   err_msg=ecos_name)


@pytest.mark.slow
def test_ecospy_gives_the_heights_of_nfal_run_to_1e_9_m(fig7_archives, ecos, jacobi_run, tmp_path):
    from nfal.orchestration.libcosim import preload_environment

    out = tmp_path / "ecos.npz"
    names = ["Plant::height", "ReferenceGenerator::reference"]
    done = subprocess.run([sys.executable, str(ECOS_SSP_OUTPUTS), str(fig7_archives["fig7_slow"]), "3.7", str(STEP),
                           str(out), *names], env=preload_environment(), capture_output=True, text=True, timeout=600,
                          check=False)
    assert out.is_file(), done.stderr[-3000:]
    theirs = np.load(out)
    assert theirs["time"].size == jacobi_run.time.size == 7401
    np.testing.assert_allclose(theirs["Plant::height"], jacobi_run["Plant.height"], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(theirs["ReferenceGenerator::reference"], jacobi_run["ReferenceGenerator.reference"])
