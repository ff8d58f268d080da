"""``nfal design`` and ``nfal compare`` through nfal.cli.main."""

import json

import pytest

from nfal.cli import main

STEP_KEYS = {"from_m", "to_m", "rise_time_s", "overshoot_percent", "settling_time_s", "noise_rms_m", "iae"}


def test_design_json_and_plot(capsys, tmp_path):
    png = tmp_path / "map.png"
    assert main(["design", "--heights", "60e-6:200e-6:8", "--placement", "continuous", "--json",
                 "--plot", str(png)]) == 0
    data = json.loads(capsys.readouterr().out)
    assert len(data["height_m"]) == len(data["kp"]) == len(data["ki"]) == len(data["kd"]) == 8
    grid = data["stability_map"]
    assert len(grid["design_height_m"]) == len(grid["operating_height_m"]) == 8
    assert len(grid["max_pole_modulus"]) == 8 and len(grid["max_pole_modulus"][0]) == 8
    assert data["units"]["ki"] == "1/s" and data["realizable_from_m"] == pytest.approx(100e-6)
    assert png.stat().st_size > 10_000 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_design_defaults_to_the_sampled_placement_and_its_realised_map(capsys):
    assert main(["design", "--heights", "50e-6:200e-6:7", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["stability_map"]["discretisation"] == "zoh" and data["realizable_from_m"] == pytest.approx(50e-6)
    assert max(max(row) for row in data["stability_map"]["max_pole_modulus"]) < 1.0


def test_design_text_output(capsys):
    assert main(["design", "--heights", "100e-6,150e-6,200e-6,250e-6", "--discretisation", "zoh"]) == 0
    out = capsys.readouterr().out
    assert "kp [m/m]" in out and "zoh" in out


@pytest.mark.parametrize("argv, message", [
    (["--heights", "50:200:4"], "--heights = [50.0, 100.0, 150.0, 200.0] is invalid: must be clearances within "
                                "1.0–1000.0 µm (did you give µm or mm as m?)"),
    (["--frequency", "28.5"], "frequency = 28.5 is invalid: must be within 500–1e+06 Hz for a levitation rig (did you "
                              "give kHz as Hz?)"),
    (["--ambient-pressure", "101.325"], "ambient_pressure = 101.325 is invalid: must be within 10000–1e+07 Pa for a "
                                        "levitation rig (did you give kPa, hPa or bar as Pa?)"),
])
def test_design_refuses_a_unit_slip_in_one_line(capsys, argv, message):
    assert main(["design", *argv]) == 2
    assert capsys.readouterr().err == f"nfal design: error: {message}\n"


def test_design_over_a_short_calibration_says_what_to_do_in_one_line(capsys, tmp_path):
    """A short identification's K (here 80-98 um) under the default 50-200 um design heights."""
    short = tmp_path / "short.json"
    short.write_text(json.dumps({"version": 1, "kind": "polynomial", "name": "short", "sigma_range": [100, 150],
                                 "coefficients": [1.2348, 2.2928e-2, -1.301e-4, 2.9826e-7, -2.4985e-10]}))
    assert main(["design", "--calibration", str(short)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("nfal design: error: design heights = 50.0–200.0 µm is invalid: must be within "
                          "80.0–98.0 µm")
    assert "nfal identify --equilibria" in err and err.count("\n") == 1


def test_compare_json_and_plot(capsys, tmp_path):
    png = tmp_path / "compare.png"
    argv = ["compare", "--controllers", "gs,160", "--levels", "100e-6,140e-6,100e-6", "--hold", "0.3", "--seed", "3",
            "--json", "--plot", str(png)]
    assert main(argv) == 0
    data = json.loads(capsys.readouterr().out)
    assert set(data["controllers"]) == {"gs", "160"}
    for result in data["controllers"].values():
        assert result["iae"] > 0 and len(result["steps"]) == 2
        assert all(set(step) >= STEP_KEYS for step in result["steps"])
    assert data["noise"]["seed"] == 3
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(argv[:-2]) == 0  # same seed, same numbers
    again = json.loads(capsys.readouterr().out)
    assert again["controllers"]["gs"]["steps"] == data["controllers"]["gs"]["steps"]


@pytest.mark.parametrize("controllers", ["gs,fast", "80,80", "30"])
def test_compare_rejects_bad_controllers(capsys, controllers):
    assert main(["compare", "--controllers", controllers, "--levels", "100e-6,120e-6", "--hold", "0.1"]) == 2
    assert "error" in capsys.readouterr().err


SHORT = ["--controllers", "gs", "--levels", "100e-6,120e-6", "--hold", "0.1"]


@pytest.mark.parametrize("argv, message", [
    (["--runs-dir", "runs"], "--runs-dir has no effect without --port (it is for the runs on the rig"),
    (["--build-dir", "build"], "--build-dir has no effect without --port"),
    (["--param", "proxy.max_missed_samples=100"], "--param has no effect without --port"),
    (["--port", "/nonexistent/port", "--seed", "3"], "--seed has no effect with --port (the rig's own sensor gives"),
    (["--port", "/nonexistent/port", "--noise-peak", "0"], "--noise-peak has no effect with --port"),
    (["--port", "/nonexistent/port", "--noise-cutoff", "300"], "--noise-cutoff has no effect with --port"),
    (["--full-schedule"], "--full-schedule has no effect without --placement continuous (the sampled placement"),
])
def test_compare_refuses_an_option_without_effect_in_its_mode(capsys, tmp_path, monkeypatch, argv, message):
    monkeypatch.chdir(tmp_path)
    assert main(["compare", *SHORT, *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"nfal compare: error: {message}") and err.count("\n") == 1
    assert not list(tmp_path.iterdir())  # nothing built, nothing run


def test_compare_refuses_levels_in_micrometres_naming_the_unit(capsys):
    assert main(["compare", "--controllers", "gs", "--levels", "60,100", "--hold", "0.1"]) == 2
    assert capsys.readouterr().err == ("nfal compare: error: --levels = [60.0, 100.0] is invalid: must be clearances "
                                       "within 1.0–1000.0 µm (did you give µm or mm as m?)\n")


def test_compare_takes_the_full_schedule_with_the_continuous_placement(capsys):
    assert main(["compare", *SHORT, "--placement", "continuous", "--full-schedule", "--seed", "0", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["noise"]["seed"] == 0


def test_design_reference_zero_changes_the_small_gaps_only(capsys):
    """The default designs through the law's reference filter (faster at small gaps); 0 is the blind design."""
    heights = ["--heights", "50e-6,100e-6,150e-6,200e-6", "--json"]
    assert main(["design", *heights]) == 0
    through = json.loads(capsys.readouterr().out)
    assert main(["design", *heights, "--reference-zero", "0"]) == 0
    blind = json.loads(capsys.readouterr().out)
    assert through["slow_pole_hz"][0] > 1.5 * blind["slow_pole_hz"][0]  # measured 10.01 against 4.92 Hz
    assert through["slow_pole_hz"][2:] == pytest.approx(blind["slow_pole_hz"][2:], rel=1e-9)
    assert main(["design", *heights, "--reference-zero", "-1"]) == 2
    assert "--reference-zero" in capsys.readouterr().err
