"""Third-party FMUs through ``nfal run``: the FMI Reference FMUs (Stair, Feedthrough; FMI 2.0, built from
modelica/Reference-FMUs, see tests/reference_fmus/README.md).

Stair counts 1, 2, ... 10 (an Integer, +1 at every whole second) and ends its own horizon at 9 s
(fmi2Discard, fmi2Terminated); Feedthrough copies each input to its output. The structures connect
Stair's Integer counter to Feedthrough's Real inputs, plain and through an ssc:LinearTransformation, and
take their start, stop and step from the SSD's DefaultExperiment.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers.shared_builds import shared_build
from reference_fmus.build import build_reference_fmus, compiler
from toy_fmus.ssd import component, connection, ssd, system, write_folder

from nfal.cli import main
from nfal.orchestration import TypeMismatchError, UnsupportedFeatureError, read_ssp, resolve, run_structure
from nfal.orchestration.resolve import check_link_types


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """The Reference FMUs built from their sources (tests/reference_fmus/), with the structures beside them: once for
    the session's workers."""
    if compiler() is None:
        pytest.skip("building the FMI Reference FMUs needs a C compiler: apt-get install gcc")
    return shared_build(tmp_path_factory, "reference_fmus", build_reference_fmus)


@pytest.fixture
def stair(reference) -> Path:
    return reference / "stair_feedthrough.ssd"


@pytest.fixture
def chain(reference) -> Path:
    return reference / "feedthrough_chain.ssd"


FACTOR, OFFSET = 0.5, -1.0  # the LinearTransformation in both SSDs
STEP = 0.2  # stair_feedthrough.ssd's baseStepSize [s]


@pytest.mark.parametrize("algorithm, delay", [("causal", 0), ("jacobi", 1)])
def test_stair_feeds_feedthrough_until_its_horizon(stair, tmp_path, algorithm, delay):
    result = run_structure(stair, algorithm=algorithm, out_dir=tmp_path, plot=False)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["status"] == "ok" and summary["error"] is None
    assert summary["step_size_s"] == STEP and summary["stop_time_s"] == 12.0  # the SSD's DefaultExperiment
    assert summary["steps_completed"] == 45 and summary["end_time_s"] == pytest.approx(9.0)  # Stair's 10th count
    assert summary["ended_early"]["element"] == "Stair" and "ended its own horizon at t = 9 s" in summary["note"]
    table = result.table()
    time, counter = table["time"], table["Stair.counter"]
    np.testing.assert_allclose(time, STEP * np.arange(46), atol=1e-12)
    np.testing.assert_array_equal(counter, np.minimum(1 + np.floor(time + 1e-9), 10))
    fed = np.concatenate([counter[:1]] * delay + [counter[:len(counter) - delay]])  # jacobi: one step late
    np.testing.assert_array_equal(table["Feedthrough.Float64_discrete_output"], fed)  # Integer -> Real, exact
    np.testing.assert_array_equal(table["Feedthrough.Float64_continuous_output"], FACTOR * fed + OFFSET)


@pytest.mark.parametrize("algorithm", ["causal", "jacobi"])
def test_nfal_run_takes_the_ssd_experiment_and_notes_the_horizon(stair, capsys, tmp_path, algorithm):
    assert main(["run", str(stair), "--algorithm", algorithm, "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "9 s in" in out and f"({algorithm}, step 0.2 s)" in out and "note: Stair ended its own horizon" in out


def test_nfal_run_flags_override_the_ssd_experiment(stair, capsys, tmp_path):
    assert main(["run", str(stair), "--start-time", "1", "--stop-time", "3", "--step", "0.5", "--out", str(tmp_path),
                 "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert (summary["start_time_s"], summary["stop_time_s"], summary["step_size_s"]) == (1.0, 3.0, 0.5)
    assert summary["status"] == "ok" and "note" not in summary


def test_linear_transformation_equals_libcosim(chain, tmp_path):
    """Real -> Real through the LinearTransformation, in our jacobi master and in OSP libcosim."""
    pytest.importorskip("libcosimpy")
    from nfal.orchestration.libcosim import run_ssp

    ramp = {"First.Float64_continuous_input": lambda t: 10.0 * t}  # 0 at t0, libcosim's value before its first step
    theirs = run_ssp(chain, inputs=ramp, observe=["Second.Float64_continuous_output"])
    ours = run_structure(chain, algorithm="jacobi", inputs=ramp, out_dir=tmp_path, plot=False).table()
    np.testing.assert_allclose(ours["time"][1:], theirs.time_s, atol=1e-12)
    # jacobi: First's output at t_k+1 is its input at t_k, which reaches Second one step later again
    expected = FACTOR * 10.0 * np.maximum(theirs.time_s - 0.2, 0.0) + OFFSET
    np.testing.assert_allclose(theirs["Second.Float64_continuous_output"], expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(ours["Second.Float64_continuous_output"][1:], theirs["Second.Float64_continuous_output"],
                               rtol=1e-15, atol=0)


def _pair(reference: Path, tmp_path: Path, start: str, end: str, transformation: str = "") -> Path:
    """Two Feedthroughs, A's ``start`` feeding B's ``end`` (with an optional transformation element)."""
    link = connection(f"A.{start}", f"B.{end}")
    if transformation:
        link = link.replace("/>", f">{transformation}</ssd:Connection>")
    text = ssd(system("pair", (component("A", "Feedthrough"), component("B", "Feedthrough")), (link,)),
               stop_time=1.0, step_size=0.1)
    return write_folder(tmp_path, text, {"Feedthrough": reference / "Feedthrough.fmu"})


LINEAR = '<ssc:LinearTransformation factor="2" offset="3"/>'


@pytest.mark.parametrize("start, end, transformation, message", [
    ("Float64_continuous_output", "Int32_input", "", "only Integer -> Real"),
    ("Boolean_output", "Float64_continuous_input", "", "only Integer -> Real"),
    ("Int32_output", "Boolean_input", "", "only Integer -> Real"),
    ("Int32_output", "Int32_input", LINEAR, "LinearTransformation needs Real ends"),
])
def test_connections_that_would_lose_meaning_are_refused(reference, tmp_path, start, end, transformation, message):
    with read_ssp(_pair(reference, tmp_path, start, end, transformation)) as structure:
        with pytest.raises(TypeMismatchError, match=message):
            resolve(structure)


@pytest.mark.parametrize("source, target, transformed", [
    ("Float64", "Float64", True), ("Float32", "Real", True), ("Int32", "Float64", False), ("Integer", "Float64", True),
    ("UInt8", "Real", False), ("Real", "Float64", False)])
def test_fmi3_type_names_are_linked_by_kind(source, target, transformed):
    """An FMI 3.0 Float64 is a Real and an Int32 an Integer, at a connection as anywhere: FMI versions mix."""
    check_link_types(source, target, transformed, "A.y -> B.u")


@pytest.mark.parametrize("source, target, transformed", [
    ("Float64", "Int32", False), ("Boolean", "Float64", False), ("Int32", "Int64", True),
    ("Enumeration", "Float64", False)])
def test_fmi3_type_names_that_would_lose_meaning_are_refused(source, target, transformed):
    with pytest.raises(TypeMismatchError):
        check_link_types(source, target, transformed, "A.y -> B.u")


@pytest.mark.parametrize("start, transformation, expected", [
    ("Int32_output", "", 7.0),  # Integer -> Real
    ("Float64_continuous_output", LINEAR, 2 * 7.0 + 3),
    ("Int32_output", LINEAR, 2 * 7.0 + 3),
])
def test_a_connection_converts_and_transforms(reference, tmp_path, start, transformation, expected):
    folder = _pair(reference, tmp_path / "ssp", start, "Float64_continuous_input", transformation)
    source = f"A.{start.replace('output', 'input')}"
    result = run_structure(folder, inputs={source: 7}, out_dir=tmp_path / "run", plot=False)
    np.testing.assert_array_equal(result["B.Float64_continuous_output"], expected)


def test_transformations_compose_through_system_connectors(reference, tmp_path):
    """A -> sub.in (x2 + 3) -> sub.B (x0.5 - 1): B receives 0.5 (2 u + 3) - 1 = u + 0.5."""
    inner = system("sub", (component("B", "Feedthrough"),),
                   (connection("in", "B.Float64_continuous_input").replace(
                       "/>", '><ssc:LinearTransformation factor="0.5" offset="-1"/></ssd:Connection>'),),
                   connectors=('<ssd:Connector name="in" kind="input"><ssc:Real/></ssd:Connector>',))
    outer = system("outer", (component("A", "Feedthrough"), inner),
                   (connection("A.Float64_continuous_output", "sub.in").replace("/>", f">{LINEAR}</ssd:Connection>"),))
    folder = write_folder(tmp_path / "ssp", ssd(outer, stop_time=0.3, step_size=0.1),
                          {"Feedthrough": reference / "Feedthrough.fmu"})
    with read_ssp(folder) as structure:
        (link,) = resolve(structure).links
    assert (link.transformation.factor, link.transformation.offset) == (1.0, 0.5)
    result = run_structure(folder, inputs={"A.Float64_continuous_input": 4.0}, out_dir=tmp_path / "run", plot=False)
    np.testing.assert_array_equal(result["sub.B.Float64_continuous_output"], 4.5)


def test_a_transformation_from_a_system_input_is_refused_not_dropped(reference, tmp_path):
    """The master drives a system input straight into its targets: a factor on that connection was ignored."""
    outer = system("outer", (component("A", "Feedthrough"),),
                   (connection("in", "A.Float64_continuous_input").replace("/>", f">{LINEAR}</ssd:Connection>"),),
                   connectors=('<ssd:Connector name="in" kind="input"><ssc:Real/></ssd:Connector>',))
    folder = write_folder(tmp_path / "ssp", ssd(outer, stop_time=0.3, step_size=0.1),
                          {"Feedthrough": reference / "Feedthrough.fmu"})
    with read_ssp(folder) as structure:
        with pytest.raises(UnsupportedFeatureError, match="LinearTransformation"):
            resolve(structure)
