import numpy as np
import pytest
from scipy import integrate

from nfal.errors import DataFormatError, InvalidParameterError
from nfal.models.excitation import PistonShape, PlateModeShape, TabulatedShape, paper_shape, parse_shape

R = np.linspace(0.0, 1.0, 20001)


@pytest.mark.parametrize("shape", [PistonShape(), PlateModeShape(1), PlateModeShape(2), PlateModeShape(3),
                                   paper_shape()], ids=repr)
def test_unit_norm_eq7(shape):
    assert integrate.trapezoid(shape(R) ** 2, R) == pytest.approx(1.0, abs=1e-7)


@pytest.mark.parametrize("n, wavenumber", [(1, 3.0005), (2, 6.2003), (3, 9.3675)])
def test_free_plate_modes_have_n_nodal_circles_and_textbook_wavenumbers(n, wavenumber):
    # Leissa, Vibration of plates: free circular plate, nu = 0.3, lambda^2 = 9.003, 38.44, 87.75
    shape = PlateModeShape(n)
    assert shape.wavenumber == pytest.approx(wavenumber, abs=2e-4)
    assert np.count_nonzero(np.diff(np.sign(shape(R)))) == n


def test_plate_mode_satisfies_free_edge_conditions():
    shape = PlateModeShape(2, poisson_ratio=0.3)
    h = 1e-4
    d2 = (shape.slope(1.0) - shape.slope(1.0 - h)) / h  # one-sided, O(h)
    assert abs(d2 + 0.3 * shape.slope(1.0)) < 1e-2 * abs(shape.slope(1.0))


@pytest.mark.parametrize("shape", [PlateModeShape(2), paper_shape()], ids=repr)
def test_slope_is_the_derivative(shape):
    x = np.linspace(0.05, 0.95, 7)
    numeric = (shape(x + 1e-6) - shape(x - 1e-6)) / 2e-6
    np.testing.assert_allclose(shape.slope(x), numeric, atol=1e-5)


def test_tabulated_shape_reproduces_the_standin_formula():
    # the stand-in file's header gives its closed form; the spline must follow it
    from scipy import special

    lam, ci, c0 = 5.25325979, 0.04659265, -0.43380077
    exact = special.j0(lam * R) + ci * special.i0(lam * R) + c0
    exact /= np.sqrt(integrate.trapezoid(exact**2, R))
    np.testing.assert_allclose(paper_shape()(R), exact, atol=2e-6)


def test_tabulated_shape_any_scale_is_normalised(tmp_path):
    path = tmp_path / "scan.csv"
    r = np.linspace(0, 1, 30)
    path.write_text("# a vibrometer scan\nR,amplitude_nm\n" + "\n".join(f"{a},{3.0 * np.cos(2 * a)}" for a in r))
    shape = TabulatedShape.from_csv(path)
    assert integrate.trapezoid(shape(R) ** 2, R) == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize("content, message", [
    ("R,e\n0,1\n0.5,1\n1,1\n", "4"),
    ("R,e\n0,1\n0.2,1\n0.1,1\n1,1\n", "increase"),
    ("R,e\n0.1,1\n0.2,1\n0.5,1\n1,1\n", "from 0 to 1"),
    ("R,e\n0,1\n0.2,x\n0.5,1\n1,1\n", "line 3 is not 2 numbers"),
    ("R,e,f\n0,1,1\n0.2,1,1\n0.5,1,1\n1,1,1\n", "two columns"),
    ("R,e\n0,0\n0.2,0\n0.5,0\n1,0\n", "zero"),
    ("", "no data"),
])
def test_bad_tables_are_clear_errors(tmp_path, content, message):
    path = tmp_path / "bad.csv"
    path.write_text(content)
    with pytest.raises(DataFormatError, match=message):
        TabulatedShape.from_csv(path)


def test_missing_file_is_a_clear_error(tmp_path):
    with pytest.raises(DataFormatError, match="cannot read"):
        TabulatedShape.from_csv(tmp_path / "absent.csv")


@pytest.mark.parametrize("spec", ["piston", "paper", "plate:2"])
def test_parse_shape(spec):
    assert parse_shape(spec).name.split()[0] in spec


@pytest.mark.parametrize("spec", ["plate:0", "plate:x", "banana"])
def test_parse_shape_rejects(spec):
    with pytest.raises(InvalidParameterError):
        parse_shape(spec)
