import json

import numpy as np
import pytest

from nfal.cli import main
from nfal.models.calibration import load_calibration, paper_calibration
from nfal.models.perturbation import piston_K_exact
from nfal.models.plant import SimplifiedPlant
from nfal.models.rig import RigParameters


def run_json(capsys, *argv):
    assert main(list(argv)) == 0
    return json.loads(capsys.readouterr().out)


def test_calibrate_numerical_json(capsys):
    out = run_json(capsys, "calibrate", "numerical", "--shape", "piston", "--sigma", "1,10,100", "--nodes", "801",
                   "--json")
    assert out["sigma"] == [1.0, 10.0, 100.0]
    np.testing.assert_allclose(out["K"], piston_K_exact(out["sigma"]), rtol=1e-4)


def test_calibrate_numerical_plot_and_calibration_file(tmp_path, capsys):
    png, table = tmp_path / "k.png", tmp_path / "k.json"
    assert main(["calibrate", "numerical", "--sigma", "5:500:20", "--plot", str(png), "--out", str(table)]) == 0
    assert "K(sigma)" in capsys.readouterr().out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    calibration = load_calibration(table)
    assert calibration.sigma_range == (5.0, 500.0)


def test_calibrate_experimental_recovers_eq17(tmp_path, capsys):
    plant = SimplifiedPlant(RigParameters(), paper_calibration())
    heights = np.linspace(50e-6, 200e-6, 12)
    data = tmp_path / "eq.csv"
    data.write_text("# synthetic\nheight_m,excitation_m\n" + "\n".join(
        f"{float(h)!r},{float(a)!r}" for h, a in zip(heights, plant.equilibrium_excitation(heights))))
    png = tmp_path / "fit.png"
    out = run_json(capsys, "calibrate", "experimental", str(data), "--json", "--plot", str(png),
                   "--out", str(tmp_path / "c.json"))
    np.testing.assert_allclose(out["coefficients"], paper_calibration().coefficients, rtol=1e-6)
    assert png.exists() and (tmp_path / "c.json").exists()


@pytest.mark.parametrize("argv, message", [
    (["calibrate", "numerical", "--shape", "plate:0"], "nodal circles"),
    (["calibrate", "numerical", "--sigma=-1,2"], "sigma"),
    (["calibrate", "experimental", "missing.csv"], "cannot read"),
    (["calibrate", "experimental", "missing.csv", "--mass", "-1"], "mass"),
    (["validate", "table1", "--cases", "z"], "cases"),
])
def test_bad_input_is_a_clear_error_with_exit_2(capsys, argv, message):
    assert main(argv) == 2
    assert message in capsys.readouterr().err


def test_malformed_list_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["calibrate", "numerical", "--sigma", "1:x:3"])
    assert stop.value.code == 2
