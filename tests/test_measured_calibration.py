import numpy as np
import pytest
from helpers.properties import examples
from hypothesis import given
from hypothesis import strategies as st

from nfal.csvdata import read_numeric_csv
from nfal.errors import DataFormatError, InvalidParameterError
from nfal.models.calibration import PAPER_COEFFICIENTS, paper_calibration
from nfal.models.measured_calibration import EquilibriumData, VoltageAmplitudeMap, fit_calibration, measured_K
from nfal.models.plant import SimplifiedPlant
from nfal.models.rig import RigParameters

RIG = RigParameters()
HEIGHTS = np.linspace(50e-6, 200e-6, 20)


def synthetic_equilibria(magnetic_force=None):
    """Equilibria that eq. (17) predicts, as the third experiment set would measure them."""
    plant = SimplifiedPlant(RIG, paper_calibration())
    force = np.zeros_like(HEIGHTS) if magnetic_force is None else magnetic_force
    # with a magnetic force the film must carry m g + F_mag: scale |a| by sqrt(1 + F / m g)
    excitation = plant.equilibrium_excitation(HEIGHTS) * np.sqrt(1 + force / plant.weight)
    return EquilibriumData(HEIGHTS, excitation, force)


def test_fit_recovers_eq17_coefficients():
    result = fit_calibration(RIG, synthetic_equilibria(), degree=4)
    np.testing.assert_allclose(result.fit.coefficients, PAPER_COEFFICIENTS, rtol=1e-6)
    assert result.report()["residual_max"] < 1e-10


def test_eq18_magnetic_force_is_accounted_for():
    force = 0.05 * np.sin(np.linspace(0, 3, HEIGHTS.size))  # N, downward
    result = fit_calibration(RIG, synthetic_equilibria(force), degree=4)
    np.testing.assert_allclose(result.fit.coefficients, PAPER_COEFFICIENTS, rtol=1e-6)


def test_noisy_measurements_give_small_residuals_and_close_fit():
    data = synthetic_equilibria()
    rng = np.random.default_rng(7)
    noisy = EquilibriumData(data.height * (1 + 1e-3 * rng.standard_normal(data.height.size)), data.excitation,
                            data.magnetic_force)
    result = fit_calibration(RIG, noisy, degree=4)
    sigma = np.linspace(*result.fit.sigma_range, 50)
    np.testing.assert_allclose(result.fit(sigma), paper_calibration()(sigma), rtol=1e-2)
    assert 0 < result.report()["residual_rms"] < 1e-2


def test_voltage_column_through_a_linear_map(tmp_path):
    data = synthetic_equilibria()
    gain = 0.05e-6  # m/V
    path = tmp_path / "eq.csv"
    path.write_text("height_m,voltage_v\n"
                    + "\n".join(f"{float(h)!r},{float(a) / gain!r}" for h, a in zip(data.height, data.excitation)))
    read = EquilibriumData.from_csv(path, VoltageAmplitudeMap.linear(gain))
    np.testing.assert_allclose(read.excitation, data.excitation, rtol=1e-12)


def test_voltage_map_table_interpolates_and_extrapolates():
    table = VoltageAmplitudeMap(np.array([10.0, 20.0, 40.0]), np.array([1e-6, 2e-6, 3e-6]))
    np.testing.assert_allclose(table([10.0, 15.0, 30.0, 60.0, 0.0]), [1e-6, 1.5e-6, 2.5e-6, 4e-6, 0.0])


def test_measured_K_is_eq16():
    data = synthetic_equilibria()
    sigma, K = measured_K(RIG, data)
    u, H = data.excitation / RIG.reference_clearance, data.height / RIG.reference_clearance
    np.testing.assert_allclose(RIG.stiffness_coefficient * u**2 * K, RIG.gravity_term * H**2, rtol=1e-12)


@pytest.mark.parametrize("content, message", [
    ("height_m\n1e-4\n2e-4\n", "excitation_m or voltage_v"),
    ("excitation_m,x\n1e-6,1\n2e-6,1\n", "height_m"),
    ("height_m,voltage_v\n1e-4,10\n2e-4,20\n", "voltage-to-amplitude map"),
    ("height_m,excitation_m\n1e-4,1e-6\n", ">= 2 rows"),
    ("height_m,excitation_m\n1e-4,1e-6\n-2e-4,1e-6\n", "> 0"),
])
def test_bad_measurement_files(tmp_path, content, message):
    path = tmp_path / "eq.csv"
    path.write_text(content)
    with pytest.raises(DataFormatError, match=message):
        EquilibriumData.from_csv(path)


def test_degree_too_high_for_the_data():
    data = EquilibriumData(HEIGHTS[:3], np.full(3, 2e-6), np.zeros(3))
    with pytest.raises(InvalidParameterError, match="degree"):
        fit_calibration(RIG, data, degree=4)


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@examples(60)
@given(rows=st.lists(st.lists(finite, min_size=3, max_size=3), min_size=1, max_size=20), header=st.booleans(),
       comments=st.lists(st.text(alphabet=st.characters(blacklist_categories=("Cs", "Cc")), max_size=20), max_size=3),
       delimiter=st.sampled_from([",", ";", "\t"]), decimal_comma=st.booleans())
def test_csv_reader_round_trips(tmp_path_factory, rows, header, comments, delimiter, decimal_comma):
    """Comma-separated, or semicolon- or tab-separated as a spreadsheet writes them, with a decimal comma or point."""
    path = tmp_path_factory.mktemp("csv") / "t.csv"
    number = (lambda v: repr(v).replace(".", ",")) if decimal_comma and delimiter != "," else repr  # noqa: E731
    lines = ([f"# {c}" for c in comments] + ([delimiter.join(["a", "B", "c"])] if header else [])
             + [delimiter.join(number(v) for v in row) for row in rows])
    path.write_text("\n".join(lines) + "\n")
    names, table = read_numeric_csv(path)
    np.testing.assert_array_equal(table, np.array(rows))
    assert names == (["a", "b", "c"] if header else ["col0", "col1", "col2"])


@examples(60)
@given(text=st.text(max_size=200))
def test_csv_reader_never_crashes_on_garbage(tmp_path_factory, text):
    path = tmp_path_factory.mktemp("csv") / "g.csv"
    path.write_text(text, encoding="utf-8")
    try:
        _, table = read_numeric_csv(path)
    except DataFormatError:
        return
    assert np.all(np.isfinite(table))


def test_csv_reader_takes_a_spreadsheets_export(tmp_path):
    """A byte-order mark, CRLF line ends and an empty cell after the last column, as spreadsheets write them."""
    path = tmp_path / "export.csv"
    path.write_bytes(b"\xef\xbb\xbftime_s,reference_m,\r\n0,6e-05,\r\n0.3,0.0001,\r\n")
    names, table = read_numeric_csv(path)
    assert names == ["time_s", "reference_m"] and table.tolist() == [[0.0, 6e-05], [0.3, 1e-04]]


def test_a_short_row_of_a_comma_table_is_named_not_read_as_decimal_commas(tmp_path):
    """'1,2' alone would be a number with a decimal comma between semicolons; a table without any is a comma table."""
    path = tmp_path / "ragged.csv"
    path.write_text("a,b\n1,2\n3\n")
    with pytest.raises(DataFormatError, match="line 3 is not 2 numbers: '3'"):
        read_numeric_csv(path)


def test_a_decimal_comma_between_commas_is_named(tmp_path):
    path = tmp_path / "comma.csv"
    path.write_text('time_s,reference_m\n0,"6,0e-5"\n')
    with pytest.raises(DataFormatError, match=r"line 2 is not 2 numbers: '0,6,0e-5' \(a decimal comma\? between "
                       r"commas, numbers take a point\)"):
        read_numeric_csv(path)


@pytest.mark.parametrize("content", [b"a,b\n1,\x002\n", b"\xff\xfe1,2\n"])
def test_csv_reader_rejects_binary(tmp_path, content):
    path = tmp_path / "b.csv"
    path.write_bytes(content)
    with pytest.raises(DataFormatError):
        read_numeric_csv(path)
