"""Running structures of toy FMUs: the two algorithms against exact discrete solutions and OSP libcosim,
algebraic loops, external inputs, failures mid-run, results and real-time pacing."""

from __future__ import annotations

import json

import numpy as np
import pytest
from toy_fmus import build_toys, without_dependencies
from toy_fmus.ssd import bindings, component, connection, connector, pack, parameter_set, ssd, system, write_folder

from nfal.errors import InvalidParameterError, UnknownConnectorError
from nfal.models.reference import Staircase
from nfal.orchestration import (AlgebraicLoopError, CausalityError, Finding, FmuCallError, Master, PlotPanel,
                                RunCheckError, read_ssp, resolve, run_structure, staircase)

X0, GAIN, DT, STEPS = 1.0, -2.0, 0.1, 20


@pytest.fixture(scope="session")
def toys(tmp_path_factory):
    return build_toys(tmp_path_factory.getbasetemp() / "toy_fmus")


@pytest.fixture()
def loop(tmp_path, toys):
    """Integrator x' = u (Plant) and gain u = k x (Controller) in a feedback loop, x0 = 1, k = -2."""
    text = ssd(system("loop", (component("Plant", "Integrator", parameter_bindings=bindings(
                                   parameter_set({"x0": ("Real", X0, "m")}))),
                               component("Controller", "Gain", parameter_bindings=bindings(
                                   parameter_set({"k": ("Real", GAIN)})))),
                      (connection("Plant.x", "Controller.u"), connection("Controller.y", "Plant.u"))),
               stop_time=STEPS * DT, step_size=DT)
    return write_folder(tmp_path / "loop", text, toys)


def exact_causal(steps: int) -> np.ndarray:
    """x_{k+1} = x_k + dt k x_k: no delay."""
    return X0 * (1 + DT * GAIN) ** np.arange(steps + 1)


def exact_jacobi(steps: int) -> np.ndarray:
    """x_{k+1} = x_k + dt k x_{k-1} (x_{-1} = x_0): the gain's output is one exchange late."""
    x = [X0, X0 + DT * GAIN * X0]
    while len(x) < steps + 1:
        x.append(x[-1] + DT * GAIN * x[-2])
    return np.array(x)


@pytest.mark.parametrize("algorithm, exact", [("causal", exact_causal), ("jacobi", exact_jacobi)])
def test_feedback_loop_matches_the_exact_discrete_solution(loop, tmp_path, algorithm, exact):
    result = run_structure(loop, algorithm=algorithm, out_dir=tmp_path / algorithm, progress=False)
    np.testing.assert_allclose(result.table().time, DT * np.arange(STEPS + 1), rtol=0, atol=1e-12)
    np.testing.assert_allclose(result["Plant.x"], exact(STEPS), rtol=1e-12, atol=1e-15)
    assert result["Plant.steps"].tolist() == list(range(STEPS + 1))
    if algorithm == "causal":  # the gain's output is consistent with the state at the same instant
        np.testing.assert_allclose(result["Controller.y"], GAIN * result["Plant.x"], rtol=1e-12)
    assert result.summary["status"] == "ok" and result.summary["steps_completed"] == STEPS


def test_jacobi_matches_osp_libcosim(loop, tmp_path, toys):
    libcosim = pytest.importorskip("libcosimpy.CosimExecution")
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    log_output_level(CosimLogLevel.ERROR)
    execution = libcosim.CosimExecution.from_step_size(step_size=int(round(DT * 1e9)))
    plant = execution.add_local_slave(CosimLocalSlave(fmu_path=str(toys["Integrator"]), instance_name="Plant"))
    gain = execution.add_local_slave(CosimLocalSlave(fmu_path=str(toys["Gain"]), instance_name="Controller"))
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    with read_ssp(loop) as structure:
        resolved = resolve(structure)
    vr = {(e.name, v.name): v.valueReference for e in resolved.elements for v in e.model_description.modelVariables}
    execution.connect_real_variables(plant, vr["Plant", "x"], gain, vr["Controller", "u"])
    execution.connect_real_variables(gain, vr["Controller", "y"], plant, vr["Plant", "u"])
    execution.real_initial_value(plant, vr["Plant", "x0"], X0)
    execution.real_initial_value(gain, vr["Controller", "k"], GAIN)
    theirs = []
    for _ in range(STEPS):
        execution.step()
        theirs.append(observer.last_real_values(plant, [vr["Plant", "x"]])[0])
    ours = run_structure(loop, algorithm="jacobi", out_dir=tmp_path / "ours", progress=False, plot=False)
    np.testing.assert_allclose(ours["Plant.x"][1:], theirs, rtol=1e-12)


def test_algebraic_loop_is_reported_with_its_variables(tmp_path, toys):
    text = ssd(system("ring", (component("A", "Gain"), component("B", "Gain")),
                      (connection("A.y", "B.u"), connection("B.y", "A.u"))), stop_time=1.0, step_size=0.1)
    folder = write_folder(tmp_path / "ring", text, toys)
    with pytest.raises(AlgebraicLoopError, match=r"A\.y -> B\.u -> B\.y -> A\.u -> A\.y") as caught:
        run_structure(folder, out_dir=tmp_path / "out", progress=False)
    assert set(caught.value.variables) == {"A.y", "B.u", "B.y", "A.u"}
    assert "nfal run --algorithm jacobi" in str(caught.value)  # the way out, as the command line spells it
    assert not (tmp_path / "out").exists()  # found before anything runs or is written
    result = run_structure(folder, algorithm="jacobi", out_dir=tmp_path / "jacobi", progress=False, plot=False)
    assert result.summary["status"] == "ok"  # jacobi breaks the loop with its delay


def test_outputs_without_dependencies_are_read_as_the_option_says(loop, tmp_path):
    without_dependencies(loop / "resources" / "Integrator.fmu", tmp_path / "bare.fmu").replace(
        loop / "resources" / "Integrator.fmu")
    with pytest.raises(AlgebraicLoopError, match="Plant.x"):  # FMI 2.0's reading: x depends on u
        run_structure(loop, out_dir=tmp_path / "all", undeclared_dependencies="all", progress=False)
    result = run_structure(loop, out_dir=tmp_path / "none", progress=False, plot=False)  # docs/cosimulation.md
    np.testing.assert_allclose(result["Plant.x"], exact_causal(STEPS), rtol=1e-12)


def test_failing_fmu_keeps_every_earlier_row(loop, tmp_path):
    out = tmp_path / "failed"
    with pytest.raises(FmuCallError) as caught:
        run_structure(loop, parameters={"Plant.fail_time": 0.5, "Plant.label": "toy plant"}, out_dir=out,
                      progress=False, flush_interval_s=10.0)
    error = caught.value
    assert error.element == "Plant" and error.function == "fmi2DoStep" and error.time == pytest.approx(0.5)
    assert "toy plant fails by design" in str(error)  # the FMU's own logged reason
    table = error.result.table()
    np.testing.assert_allclose(table.time, DT * np.arange(6), atol=1e-12)
    np.testing.assert_allclose(table["Plant.x"], exact_causal(5), rtol=1e-12)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and summary["steps_completed"] == 5
    assert summary["error_detail"]["element"] == "Plant" and "fails by design" in summary["error"]


def test_external_input_on_a_system_connector_and_on_an_element_input(tmp_path, toys):
    reference = staircase((1.0, 3.0), hold_s=1.0, lead_s=0.45)
    text = ssd(system("open", (component("Controller", "Gain"), component("Plant", "Integrator")),
                      (connection("reference", "Controller.u"),), connectors=(connector("reference", "input"),)))
    folder = write_folder(tmp_path / "open", text, toys)
    result = run_structure(folder, stop_time=1.0, step_size=0.1, out_dir=tmp_path / "out", progress=False,
                           inputs={"reference": reference, "Plant.u": lambda t: 2.0 * t},
                           parameters={"Controller.k": 10.0})
    table = result.table()
    expected_reference = np.where(table.time < 0.45, 1.0, 3.0)
    np.testing.assert_allclose(table["reference"], expected_reference)
    np.testing.assert_allclose(table["Controller.y"], 10.0 * expected_reference)
    # x' = u with u held at 2 t_k over each step: x_k = sum 2 t_j dt
    np.testing.assert_allclose(table["Plant.x"], np.concatenate([[0.0], np.cumsum(2 * table.time[:-1] * 0.1)]),
                               atol=1e-12)
    assert table.unit("Plant.u") == "m/s"


def test_staircase_drives_an_input_like_the_python_loop_sees_it(tmp_path, toys):
    text = ssd(system("gain", (component("Controller", "Gain"),)))
    folder = write_folder(tmp_path / "gain", text, toys)
    stairs = Staircase()
    result = run_structure(folder, stop_time=stairs.duration_s, step_size=5e-4, inputs={"Controller.u": stairs},
                           out_dir=tmp_path / "out", progress=False, plot=False)
    table = result.table()
    time_s = np.arange(stairs.samples(2000)) * 5e-4
    np.testing.assert_array_equal(table["Controller.u"][:-1], stairs(time_s))


@pytest.mark.parametrize("inputs, error", [
    ({"Controller.k": 1.0}, CausalityError),  # a parameter
    ({"Plant.x": 1.0}, CausalityError),  # an output ("is a output", it said)
    ({"Controller.nothing": 1.0}, UnknownConnectorError),
])
def test_bad_external_inputs_are_named(loop, tmp_path, inputs, error):
    with pytest.raises(error, match=list(inputs)[0].replace(".", r"\.")) as raised:
        run_structure(loop, inputs=inputs, out_dir=tmp_path, progress=False)
    assert " a output" not in str(raised.value)


@pytest.mark.parametrize("algorithm", ["causal", "jacobi"])
def test_an_external_input_replaces_the_connection_it_names(loop, tmp_path, algorithm):
    """A host's override: Controller.u held at 0.5 instead of Plant.x, so y = k 0.5 and x' = k 0.5 (a ramp)."""
    result = run_structure(loop, inputs={"Controller.u": 0.5}, algorithm=algorithm, out_dir=tmp_path, progress=False,
                           plot=False)
    np.testing.assert_array_equal(result["Controller.u"], 0.5)
    np.testing.assert_allclose(result["Controller.y"], GAIN * 0.5, rtol=1e-12)
    np.testing.assert_allclose(result["Plant.x"], X0 + GAIN * 0.5 * DT * np.arange(STEPS + 1), rtol=1e-12, atol=1e-14)
    assert "Plant.x -> Controller.u" in result.summary["connections"]  # the structure's, as written
    assert result.summary["exchange_order"] and result.summary["status"] == "ok"


def decayed(table) -> list[Finding]:
    """A check of the toy loop that fails: x falls to 0.8**20 = 0.0115 in 2 s, not below 1e-3."""
    return [Finding("x never fell below 0.001", failure=True)] if table["Plant.x"].min() >= 1e-3 else []


def test_a_check_finds_nothing_the_run_is_ok(loop, tmp_path):
    result = run_structure(loop, out_dir=tmp_path, progress=False, plot=False, checks=lambda table: [])
    assert json.loads((tmp_path / "summary.json").read_text())["warnings"] == []
    assert (result.summary["status"], result.summary["warnings"]) == ("ok", [])


def test_a_checks_warning_keeps_the_run_ok_with_the_warning(loop, tmp_path):
    result = run_structure(loop, out_dir=tmp_path, progress=False, plot=False,
                           checks=lambda table: [Finding("x never fell below 1e-08")])
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert (summary["status"], summary["warnings"], summary["error"]) == ("ok", ["x never fell below 1e-08"], None)
    assert result.summary == summary


def test_a_failed_check_fails_a_completed_run_and_keeps_every_row(loop, tmp_path):
    with pytest.raises(RunCheckError, match="x never fell below 0.001") as caught:
        run_structure(loop, out_dir=tmp_path, progress=False, plot=False, checks=decayed)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert (summary["status"], summary["error"], summary["warnings"]) == ("failed", "x never fell below 0.001", [])
    assert summary["steps_completed"] == STEPS and len(caught.value.result.table()) == STEPS + 1


def test_a_check_that_breaks_is_recorded_not_raised(loop, tmp_path):
    result = run_structure(loop, out_dir=tmp_path, progress=False, plot=False, checks=lambda table: table["nothing"])
    assert result.summary["status"] == "ok" and "nothing" in result.summary["checks_error"]


def test_results_files(loop, tmp_path):
    out = tmp_path / "out"
    run_structure(pack(loop, tmp_path / "loop.ssp"), out_dir=out, progress=False,
                  plot=[PlotPanel(("Plant.x",), 1e6, "x [um]"), ("Controller.y",)],
                  metrics=lambda table: {"final_x_m": float(table["Plant.x"][-1])})
    header = (out / "results.csv").read_text().splitlines()[0]
    assert header == "time [s],Plant.x [m],Plant.steps,Controller.y"
    assert (out / "response.png").stat().st_size > 1000
    summary = json.loads((out / "summary.json").read_text())
    assert summary["metrics"]["final_x_m"] == pytest.approx(exact_causal(STEPS)[-1])
    assert summary["exchange_order"] == ["doStep all from t_k", "get Plant.x, Plant.steps (at t_k+1)",
                                         "set Controller.u (at t_k+1)", "get Controller.y (at t_k+1)",
                                         "set Plant.u (at t_k+1)"]
    assert set(summary["timing"]) == {"Plant", "Controller"} and summary["timing"]["Plant"]["do_step_total_s"] > 0
    assert summary["step_size_s"] == DT and summary["stop_time_s"] == pytest.approx(STEPS * DT)
    assert summary["realtime"] is None and summary["elements"]["Plant"]["start_values"] == {"x0": X0}


def test_integer_boolean_and_string_parameters_reach_the_fmu(loop, tmp_path):
    result = run_structure(loop, parameters={"Plant.decimation": 2, "Plant.frozen": False, "Plant.label": "p"},
                           out_dir=tmp_path, progress=False, plot=False)
    x = result["Plant.x"]
    assert x[1] != x[0] and x[2] == x[1]  # integrates every second step only
    frozen = run_structure(loop, parameters={"Plant.frozen": True}, out_dir=tmp_path / "frozen", progress=False,
                           plot=False)
    assert np.all(frozen["Plant.x"] == X0)


def test_a_parameter_the_fmu_rejects_at_initialisation_is_reported(loop, tmp_path):
    with pytest.raises(FmuCallError, match=r"(?s)Plant.*decimation = 0 must be >= 1"):
        run_structure(loop, parameters={"Plant.decimation": 0}, out_dir=tmp_path, progress=False)


def test_master_steps_by_hand_and_frees_its_fmus(loop):
    with read_ssp(loop) as structure:
        with Master(resolve(structure), step_size=DT) as master:
            master.instantiate()
            master.initialize(0.0, 1.0)
            for _ in range(3):
                master.step()
            assert master.time == pytest.approx(0.3)
            assert master.row[master.columns.index(next(c for c in master.columns if c.name == "Plant.x"))] == \
                pytest.approx(exact_causal(3)[-1])
        assert all(slave.state == "freed" for slave in master.slaves)


def test_realtime_run_keeps_to_the_wall_clock_and_reports_jitter(loop, tmp_path):
    result = run_structure(loop, stop_time=0.3, step_size=0.01, realtime=True, out_dir=tmp_path, progress=False,
                           plot=False)
    assert result.summary["loop_wall_time_s"] >= 0.3  # never ahead of the clock (how far behind: the machine's load)
    report = result.summary["realtime"]
    assert report["steps"] == 30 and report["period_s"] == pytest.approx(0.01)
    for key in ("overruns", "jitter_max_s", "jitter_mean_s", "jitter_p95_s", "step_duration_max_s"):
        assert report[key] >= 0
    assert report["jitter_p50_s"] <= report["jitter_p95_s"] <= report["jitter_max_s"]
    assert report["gc_pauses"]["count"] >= 0 and "memory_locked" in report  # the real-time section's report


def test_faster_than_real_time_when_asked(loop, tmp_path):
    result = run_structure(loop, stop_time=0.4, step_size=0.01, realtime=4.0, out_dir=tmp_path, progress=False,
                           plot=False)
    assert result.summary["loop_wall_time_s"] >= 0.1


def test_a_step_longer_than_the_run_is_one_error_and_no_warning_that_the_run_ends_early(caplog):
    from nfal.errors import InvalidParameterError
    from nfal.orchestration import run

    with caplog.at_level("WARNING", logger=run.__name__):
        with pytest.raises(InvalidParameterError, match=r"at least one step \(10 s\)"):
            run._step_count(0.0, 3.7, 10.0)
        assert not caplog.records
        assert run._step_count(0.0, 3.7, 1.0) == 3
    assert [r.getMessage() for r in caplog.records] == [
        "stop time 3.7 s is not a whole number of 1 s steps from 0 s: the run ends at 3 s"]


def test_a_system_input_whose_targets_are_driven_directly_is_not_said_to_be_undriven(tmp_path, toys, caplog):
    """A system input ``in`` feeds Controller.u; the run drives Controller.u itself (as nfal run drives
    Controller.reference): the warning that ``in`` is not driven and Controller.u keeps its start value was false.
    Driving ``in`` by its name works as well."""
    text = ssd(system("open", (component("Controller", "Gain"),), (connection("in", "Controller.u"),),
                      connectors=(connector("in", "input"),)), stop_time=3 * DT, step_size=DT)
    folder = write_folder(tmp_path / "open", text, toys)
    outputs = []
    for name in ("Controller.u", "in"):
        caplog.clear()
        result = run_structure(folder, inputs={name: 2.0}, out_dir=tmp_path / name, progress=False, plot=False)
        assert "not driven" not in caplog.text
        outputs.append(result["Controller.y"][-1])
    assert outputs[0] == outputs[1] != 0.0


def test_a_structure_without_a_step_says_which_option_gives_it(tmp_path, toys):
    """An SSD from a tool that writes its step in its own annotation (OMSimulator's): the step is asked for as the
    command line gives it (the message said 'step_size = None is invalid')."""
    text = ssd(system("one", (component("A", "Gain"),)), stop_time=1.0)
    with pytest.raises(InvalidParameterError, match=r"nfal run --step S.*other tools are not read"):
        run_structure(write_folder(tmp_path / "one", text, toys), out_dir=tmp_path / "out", progress=False)
