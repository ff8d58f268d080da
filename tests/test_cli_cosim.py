"""``nfal build`` and ``nfal run`` through nfal.cli.main."""

import json

import pytest

from nfal.cli import main
from nfal.commands.cosim import parse_parameter
from nfal.errors import InvalidParameterError


@pytest.mark.slow  # whole runs of the loop
def test_build_packs_every_structure(capsys, tmp_path):
    assert main(["build", "--out", str(tmp_path), "--json"]) == 0
    archives = json.loads(capsys.readouterr().out)
    assert set(archives) == {"fig7_slow", "fig7_reynolds", "fig7_hil", "rig_slow", "rig_reynolds"}
    assert sorted(p.name for p in tmp_path.glob("*.fmu")) == [
        "Controller.fmu", "HardwareProxy.fmu", "ReferenceGenerator.fmu", "ResonanceTracker.fmu", "ReynoldsPlant.fmu",
        "SensorChain.fmu", "SlowPlant.fmu"]


@pytest.mark.slow  # whole runs of the loop
def test_run_writes_results_summary_and_plot(capsys, tmp_path, fig7_archives):
    out = tmp_path / "run"
    assert main(["run", str(fig7_archives["fig7_slow"]), "--stop-time", "0.2", "--out", str(out), "--json",
                 "--param", "Controller.design=fixed", "--param", "Controller.design_height=100e-6"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["status"] == "ok" and summary["steps"] == 400
    assert summary["elements"]["Controller"]["start_values"]["design"] == "fixed"
    assert (out / "results.csv").read_text().startswith("time [s],")
    assert json.loads((out / "summary.json").read_text())["status"] == "ok"
    assert (out / "response.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow  # whole runs of the loop
def test_run_from_a_reference_csv(capsys, tmp_path, fig7_archives):
    csv = tmp_path / "reference.csv"
    csv.write_text("# time_s,reference_m\n0,60e-6\n0.05,80e-6\n")
    assert main(["run", str(fig7_archives["fig7_slow"]), "--reference", str(csv), "--stop-time", "0.3",
                 "--out", str(tmp_path / "run")]) == 0
    out = capsys.readouterr().out
    assert "0.3 s" in out and "IAE" not in out  # metrics only for the staircase


@pytest.mark.slow  # whole runs of the loop
def test_default_run_prints_the_step_metrics(capsys, tmp_path, monkeypatch, fig7_archives):
    """`nfal run` with no structure: builds into build/ (here reused from the session) and runs fig7_slow."""
    monkeypatch.chdir(tmp_path)
    build = fig7_archives["fig7_slow"].parent
    assert main(["run", "--build-dir", str(build)]) == 0
    out = capsys.readouterr().out
    assert "IAE" in out and "100 ->  140" in out
    assert len(list((tmp_path / "runs").glob("fig7_slow-*/results.csv"))) == 1


@pytest.mark.parametrize("argv, message", [
    (["run", "no_such.ssp"], "structure"),
    (["run", "fig7_slow", "--param", "Controller"], "--param"),
    (["run", "fig7_slow", "--param", "Plant.mass=-1", "--stop-time", "0.01"], "mass"),
])
def test_bad_input_is_a_clear_error(capsys, tmp_path, monkeypatch, fig7_archives, argv, message):
    monkeypatch.chdir(tmp_path)
    argv = argv + ["--build-dir", str(fig7_archives["fig7_slow"].parent)]
    assert main(argv) == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize("text, expected", [("A.b=1e-6", ("A.b", "1e-6")), ("A.flag= true", ("A.flag", "true")),
                                            ("A.design=fixed", ("A.design", "fixed"))])
def test_parse_parameter(text, expected):
    assert parse_parameter(text) == expected


@pytest.mark.parametrize("text", ["A=1", "A.b", "A.b=", "A.b= "])
def test_parse_parameter_rejects(text):
    with pytest.raises(InvalidParameterError):
        parse_parameter(text)


@pytest.mark.slow  # whole runs of the loop
@pytest.mark.parametrize("pll, settles_near", [("true", 28557.0), ("false", 28500.0)])
def test_run_drives_a_resonance_drift_input(capsys, tmp_path, fig7_archives, pll, settles_near):
    """--input drives a second input: a 57 Hz (0.2 %) resonance step; the PLL follows it, a fixed drive does not."""
    from nfal.orchestration import read_results

    out = tmp_path / "run"
    assert main(["run", str(fig7_archives["fig7_slow"]), "--stop-time", "0.4", "--out", str(out), "--json",
                 "--input", "ResonanceTracker.resonance_shift=step:0,57,0.15",
                 "--param", f"ResonanceTracker.pll_enabled={pll}"]) == 0
    capsys.readouterr()
    table = read_results(out / "results.csv")
    assert table["ResonanceTracker.drive_frequency"][-1] == pytest.approx(settles_near, abs=1.0)


@pytest.mark.parametrize("text", ["ResonanceTracker", "A.b=", "A.b=wobble:3"])
def test_bad_input_signal_is_a_clear_error(capsys, tmp_path, fig7_archives, text):
    assert main(["run", str(fig7_archives["fig7_slow"]), "--stop-time", "0.01", "--out", str(tmp_path / "r"),
                 "--input", text]) == 2
    assert "error" in capsys.readouterr().err


def test_run_of_the_hil_structure_asks_for_the_port_before_anything_runs(capsys, tmp_path, fig7_archives):
    assert main(["run", str(fig7_archives["fig7_hil"]), "--out", str(tmp_path / "run")]) == 2
    assert "--param proxy.port=PORT" in capsys.readouterr().err and not (tmp_path / "run").exists()
