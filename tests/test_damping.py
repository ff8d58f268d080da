"""DampingCorrection (models/damping.py) and the calibration file that carries it (models/calibration.py):
the contract between ``nfal identify`` (writes) and the plants, the LPV model and the designs (read)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nfal.errors import DataFormatError, InvalidParameterError
from nfal.models.calibration import (CALIBRATION_FILE_VERSION, RigCalibration, load_calibration, load_rig_calibration,
                                     paper_calibration, rig_record)
from nfal.models.damping import DampingCorrection
from nfal.models.fixed_step_plant import FixedStepPlant
from nfal.models.lpv import lpv_coefficients
from nfal.models.plant import ExcessDamping, PlantState, SimplifiedPlant
from nfal.models.rig import RigParameters

RIG = RigParameters()
HEIGHTS = np.array([50e-6, 75e-6, 100e-6, 130e-6, 160e-6, 200e-6])
#: A table sampled from the rig-like ExcessDamping, as an identification would measure it.
RIG_LIKE = ExcessDamping.rig_like()
TABLE = DampingCorrection(HEIGHTS, RIG_LIKE.factor(HEIGHTS), 0.9 * RIG_LIKE.factor(HEIGHTS),
                          1.1 * RIG_LIKE.factor(HEIGHTS))


def test_table_passes_through_its_points_and_holds_outside():
    np.testing.assert_allclose(TABLE.factor(HEIGHTS), RIG_LIKE.factor(HEIGHTS), rtol=1e-12)
    assert TABLE.factor(20e-6) == pytest.approx(TABLE.factor(50e-6), rel=1e-15)
    assert TABLE.factor(400e-6) == pytest.approx(TABLE.factor(200e-6), rel=1e-15)


def test_interpolation_is_monotone_and_close_to_the_smooth_law():
    """PCHIP on log f keeps a monotone table monotone; between the 6 points it follows the law it samples."""
    h = np.linspace(50e-6, 200e-6, 601)
    f = TABLE.factor(h)
    assert np.all(np.diff(f) >= 0)
    np.testing.assert_allclose(f, RIG_LIKE.factor(h), rtol=0.06)


@pytest.mark.parametrize("height", [30e-6, 50e-6, 61.3e-6, 99.9e-6, 100e-6, 187.2e-6, 250e-6])
def test_scalar_path_equals_the_array_path(height):
    assert TABLE.factor_scalar(height) == pytest.approx(float(TABLE.factor(height)), rel=1e-13)


def test_band_interpolates_like_the_factor():
    low, high = TABLE.factor_band(HEIGHTS)
    np.testing.assert_allclose(low, 0.9 * RIG_LIKE.factor(HEIGHTS), rtol=1e-12)
    np.testing.assert_allclose(high, 1.1 * RIG_LIKE.factor(HEIGHTS), rtol=1e-12)


@pytest.mark.parametrize("heights, factors, low, high, reason", [
    ([50e-6], [1.0], None, None, ">= 2 heights"),
    ([50e-6, 40e-6], [1.0, 2.0], None, None, "strictly increasing"),
    ([50e-6, 60e-6], [1.0, -2.0], None, None, "0 < factors_low"),
    ([50e-6, 60e-6], [1.0, 2.0], [1.1, 1.5], [1.2, 2.5], "factors_low <= factors"),
    ([50e-6, 60e-6], [1.0, float("nan")], None, None, "finite"),
    ([50e-6, 60e-6], ["a", 1.0], None, None, "list of numbers"),
    ([50e-6, 60e-6, 70e-6], [1.0, 2.0], None, None, "one factor"),
])
def test_bad_tables_raise(heights, factors, low, high, reason):
    with pytest.raises(DataFormatError, match=reason):
        DampingCorrection(heights, factors, low, high)


# --- in the plants and the LPV model -------------------------------------------------------------------
def test_plants_take_the_table_like_the_parametric_correction():
    plant = SimplifiedPlant(RIG, paper_calibration(), excess_damping=TABLE)
    assert plant.squeeze_film_damping(130e-6) == pytest.approx(
        RIG.squeeze_film_damping(130e-6) * RIG_LIKE.factor(130e-6), rel=1e-12)
    state, excitation = PlantState(150e-6, 1e-3), float(plant.equilibrium_excitation(150e-6))
    exact, fast = plant.advance(state, excitation, 5e-4), FixedStepPlant(plant).advance(state, excitation, 5e-4)
    assert fast.height == pytest.approx(exact.height, abs=1e-10)


def test_plant_refuses_another_kind_of_damping():
    with pytest.raises(InvalidParameterError, match="DampingCorrection"):
        SimplifiedPlant(RIG, paper_calibration(), excess_damping=2.0)


@pytest.mark.parametrize("height", [60e-6, 130e-6, 190e-6])
def test_lpv_damping_is_scaled_by_the_factor(height):
    plain, corrected = lpv_coefficients(height, RIG), lpv_coefficients(height, RIG, damping=TABLE)
    assert float(corrected.alpha1) == pytest.approx(float(plain.alpha1) * float(TABLE.factor(height)), rel=1e-12)
    for name in ("alpha0", "beta0", "excitation_m"):
        assert float(getattr(corrected, name)) == float(getattr(plain, name))


# --- the calibration file -------------------------------------------------------------------------------
PROVENANCE = {"date": "2026-11-24T19:00:00Z", "port": "socket://localhost:7777", "firmware": "1.2", "raw": "raw.csv"}
RIG_FIELDS = rig_record(RIG)


def test_rig_record_names_every_checked_field():
    assert RIG_FIELDS == {"mass": 0.1347, "radius": 0.05, "frequency": 28.5e3, "viscosity": 1.81e-5,
                          "ambient_pressure": 101_325.0, "gravity": 9.81}


def test_file_round_trip_keeps_k_damping_rig_and_provenance(tmp_path):
    path = tmp_path / "rig.json"
    RigCalibration(paper_calibration(), TABLE, RIG_FIELDS, PROVENANCE).save(path)
    data = json.loads(path.read_text())
    assert data["version"] == CALIBRATION_FILE_VERSION and data["provenance"] == PROVENANCE
    loaded = load_rig_calibration(path, RIG)
    np.testing.assert_array_equal(loaded.damping.factors, TABLE.factors)
    np.testing.assert_array_equal(loaded.damping.factors_high, TABLE.factors_high)
    assert loaded.provenance == PROVENANCE and loaded.rig == RIG_FIELDS
    assert loaded.calibration(123.0) == paper_calibration()(123.0)
    assert load_calibration(path)(123.0) == paper_calibration()(123.0)  # K-only readers keep working


def test_a_file_saved_with_a_byte_order_mark_loads(tmp_path):
    """An editor's "UTF-8 with BOM" (json.loads refused the mark: 'Unexpected UTF-8 BOM')."""
    path = tmp_path / "rig.json"
    RigCalibration(paper_calibration(), TABLE, RIG_FIELDS, PROVENANCE).save(path)
    path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
    assert load_rig_calibration(path, RIG).provenance == PROVENANCE


def test_k_only_files_of_older_releases_load(tmp_path):
    path = tmp_path / "k.json"
    path.write_text(json.dumps(paper_calibration().to_dict()))  # no version, no damping
    loaded = load_rig_calibration(path, RIG)
    assert loaded.damping is None and loaded.rig is None and loaded.provenance == {}


def _write(tmp_path, **extra) -> str:
    path = tmp_path / "c.json"
    path.write_text(json.dumps({**paper_calibration().to_dict(), **extra}))
    return str(path)


@pytest.mark.parametrize("extra, reason", [
    ({"version": 2}, "version = 2 is invalid: must be 1, the file format this nfal reads"),
    ({"version": "1"}, 'version = "1" is invalid: must be 1'),
    ({"version": True}, "version = true is invalid: must be 1"),
    ({"version": 1.0}, "version = 1.0 is invalid: must be 1"),
    ({"damping": {"heights_m": [50e-6, 60e-6]}}, "damping = .* is invalid: must hold heights_m and factors"),
    ({"damping": {"heights_m": [50e-6, 60e-6], "factors": [1, 2], "factor": 3}}, "damping = .*nothing else"),
    ({"damping": {"heights_m": [49.2, 80, 120, 200], "factors": [1, 2, 3, 4]}},
     r"damping.heights_m = \[49.2, 80.0, 120.0, 200.0\] is invalid: must be clearances within 1.0–1000.0 µm "
     r"\(did you give µm or mm as m\?\)"),
    ({"damping": {"heights_m": [0.5e-6, 60e-6], "factors": [1, 2]}}, "damping.heights_m = .* within 1.0–1000.0 µm"),
    ({"damping": {"heights_m": [50e-6, 60e-6], "factors": [1, True]}},
     r"damping.factors\[1\] = true is invalid: must be a finite number"),
    ({"damping": {"heights_m": [50e-6, 60e-6], "factors": [1, float("nan")]}},
     r"damping.factors\[1\] = NaN is invalid: must be a finite number"),
    ({"damping": {"heights_m": "50e-6", "factors": [1, 2]}},
     'damping.heights_m = "50e-6" is invalid: must be a list of numbers'),
    ({"rig": {"mass": -1.0}}, "rig.mass = -1.0 is invalid: must be a finite number > 0"),
    ({"rig": {"mass": 134.7}}, r"rig.mass = 134.7 is invalid: must be at most 100 kg .*grams as kg"),
    ({"rig": {"mass": True}}, "rig.mass = true is invalid: must be a finite number"),
    ({"rig": {"colour": 1.0}}, r'rig = \{"colour": 1.0\} is invalid: must map some of mass, radius'),
    ({"provenance": "yesterday"}, 'provenance = "yesterday" is invalid: must be a JSON object'),
    ({"dampin": {}}, r"unknown entries \['dampin'\] in a calibration file"),
    ({"name": 3}, "name = 3 is invalid: must be a string"),
    ({"coefficients": [1.2, True]}, r"coefficients\[1\] = true is invalid: must be a finite number"),
    ({"sigma_range": [10, "500"]}, r'sigma_range\[1\] = "500" is invalid: must be a finite number'),
    ({"sigma_range": [10, 100, 500]}, r"sigma_range = \[10.0, 100.0, 500.0\] is invalid: must be two squeeze numbers"),
])
def test_bad_files_name_the_field_its_value_and_the_range(tmp_path, extra, reason):
    with pytest.raises(DataFormatError, match=f"^calibration .*c.json: {reason}") as caught:
        load_rig_calibration(_write(tmp_path, **extra))
    assert "\n" not in str(caught.value)


@pytest.mark.parametrize("field, values, shown", [
    ("sigma", [10, 30, True, 300], "true"), ("K", [1.0, 1.1, 1.2, False], "false"),
    ("K", [1.0, float("nan"), 1.2, 1.3], "NaN"), ("K", [1.0, float("inf"), 1.2, 1.3], "Infinity"),
])
def test_a_tables_numbers_are_finite_numbers(tmp_path, field, values, shown):
    table = {"kind": "table", "name": "t", "sigma": [10, 30, 100, 300], "K": [1.0, 1.1, 1.2, 1.3], field: values}
    path = tmp_path / "t.json"
    path.write_text(json.dumps(table))
    with pytest.raises(DataFormatError, match=rf"{field}\[\d\] = {shown} is invalid: must be a finite number"):
        load_rig_calibration(path)


def test_a_damping_table_in_micrometres_is_refused_not_held_at_one_factor():
    with pytest.raises(InvalidParameterError, match="heights_m = .* within 1.0–1000.0 µm"):
        DampingCorrection([49.2, 80.0, 120.0, 200.0], [1.0, 1.5, 2.0, 4.0])


@pytest.mark.parametrize("field, value", [("mass", 0.2), ("frequency", 40e3), ("radius", 0.03)])
def test_another_rigs_file_is_refused(tmp_path, field, value):
    path = _write(tmp_path, rig={**RIG_FIELDS, field: value})
    with pytest.raises(DataFormatError, match=f"another rig \\({field} {value:g} there"):
        load_rig_calibration(path, RIG)
    assert load_rig_calibration(path, RIG.replace(**{field: value})).rig[field] == value


# --- the CLI reads the file's damping (the SlowPlant FMU: tests/test_excess_damping.py) -----------------------
@pytest.fixture()
def identified_file(tmp_path):
    path = tmp_path / "identified.json"
    RigCalibration(paper_calibration(), TABLE, RIG_FIELDS, PROVENANCE).save(path)
    return str(path)


def test_cli_design_uses_the_files_damping(capsys, identified_file):
    from nfal.cli import main  # the front door, only for these tests

    arguments = ["design", "--heights", "120e-6,150e-6,180e-6,200e-6", "--placement", "sampled", "--json"]
    assert main(arguments) == 0
    plain = json.loads(capsys.readouterr().out)
    assert main(arguments + ["--calibration", identified_file]) == 0
    corrected = json.loads(capsys.readouterr().out)
    assert corrected["kd"][-1] != pytest.approx(plain["kd"][-1], rel=1e-3)
    assert max(max(row) for row in corrected["stability_map"]["max_pole_modulus"]) < 1.0


@pytest.mark.parametrize("extra, message", [({"version": 7}, "version = 7 is invalid: must be 1"),
                                            ({"rig": {"mass": 0.5}}, "another rig")])
def test_cli_refuses_a_bad_file_with_exit_2(capsys, tmp_path, extra, message):
    from nfal.cli import main  # the front door, only for these tests

    assert main(["design", "--heights", "100e-6,150e-6,180e-6,200e-6", "--calibration", _write(tmp_path, **extra)]) == 2
    assert message in capsys.readouterr().err
