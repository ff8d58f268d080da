"""``nfal reproduce``: the paper's numbers (one data file), how each of ours is judged against them, and the whole
report, whose every judged number must hold or be a known difference."""

import json

import pytest

from nfal.cli import main
from nfal.models.calibration import PAPER_COEFFICIENTS
from nfal.models.paper_numbers import paper_numbers, paper_value
from nfal.models.table1 import TABLE1
from nfal.apps.reproduce import KNOWN_DIFFERENCES, SECTIONS, _compare, reproduce

#: One worker builds the report for all of them (a minute): with --dist loadgroup a test is handed out alone otherwise.
pytestmark = pytest.mark.xdist_group("reproduce")


def test_every_paper_number_says_where_it_is_from_and_what_it_is():
    numbers = paper_numbers()
    assert len(numbers) >= 40
    for number in numbers.values():
        assert number.where and number.what, number.id
        assert number.relation in ("=", "<", "~"), number.id
        assert isinstance(number.value, (bool, int, float)), number.id


def test_eq17_and_table1_are_read_from_the_data_file():
    assert PAPER_COEFFICIENTS == (1.2348, 2.2928e-2, -1.301e-4, 2.9826e-7, -2.4985e-10)
    assert [(c.name, c.mass, c.frequency, c.excitation, c.paper_delta, c.paper_error_percent) for c in TABLE1][3] == \
        ("d", 20.0, 2000, 4e-6, 0.3244, 2.3425)


@pytest.mark.parametrize(("key", "ours", "holds"), [
    ("fig6.steady_state_deviation", 1.99, True), ("fig6.steady_state_deviation", 2.0, False),  # "< 2 %"
    ("fig6.rise_time_ratio_190um", 6.0, True), ("fig6.rise_time_ratio_190um", 5.9, False),     # "about 9": x/1.5
    ("fig6.rise_time_ratio_190um", 13.5, True), ("fig6.rise_time_ratio_190um", 13.6, False),
    ("table1.a.delta", 0.0696 * 1.004, True), ("table1.a.delta", 0.0696 * 1.006, False),       # 0.5 %
    ("table1.d.error", 2.3425 / 1.99, True), ("table1.d.error", 2.3425 * 2.01, False),         # a factor 2
    ("fig9_10.gs_best", True, True), ("fig9_10.gs_best", False, False),                        # a claim
])
def test_a_number_is_judged_by_its_relation_and_tolerance(key, ours, holds):
    assert _compare(key, ours).holds is holds


def test_a_number_with_no_tolerance_is_shown_not_judged():
    comparison = _compare("eq17.c0", 1.3)
    assert comparison.holds is None and comparison.difference == pytest.approx(1.3 - paper_value("eq17.c0"))


@pytest.fixture(scope="module")
def report(tmp_path_factory, fig7_archives):
    return reproduce(tmp_path_factory.mktemp("reproduce"), build_dir=fig7_archives["fig7_hil"].parent)


@pytest.mark.slow
def test_every_judged_number_holds_or_is_a_known_difference(report):
    unexpected = {c.key: (c.ours, c.tolerance) for c in report.unexpected}
    assert not unexpected, unexpected
    judged = {c.key for c in report.comparisons if c.holds is not None}
    assert set(KNOWN_DIFFERENCES) <= judged
    assert len(judged) >= 20
    assert [s.figure for s in report.sections] == ["fig4.png", "fig5.png", "fig6.png", "fig8.png", "fig9_10.png",
                                                     "fig11_12.png"]  # the paper's order (Fig. 6 runs first)
    assert len(report.sections) == len(SECTIONS)


@pytest.mark.slow
def test_the_report_has_every_figure_and_number(report):
    saved = json.loads((report.out_dir / "report.json").read_text())
    page = (report.out_dir / "report.html").read_text()
    for section in report.sections:
        assert (report.out_dir / section.figure).stat().st_size > 10_000
        assert f'src="{section.figure}"' in page
    rows = [c for s in saved["sections"] for c in s["comparisons"]]
    assert [row["key"] for row in rows] == [c.key for c in report.comparisons]
    assert all(row["paper"] == paper_value(row["paper_id"]) for row in rows)
    assert saved["unexpected"] == [] and saved["hold"] == saved["judged"] - len(KNOWN_DIFFERENCES)


@pytest.mark.slow
def test_the_command_refuses_to_replace_a_report(report, capsys):
    assert main(["reproduce", "--out", str(report.out_dir)]) == 2
    assert "already holds a report" in capsys.readouterr().err


@pytest.mark.parametrize(("key", "name", "design"), [
    ("gs", "gain-scheduled", {"Controller.design": "gain-scheduled"}),
    ("80", "linear at 80 um", {"Controller.design": "fixed", "Controller.design_height": pytest.approx(80e-6)}),
])
def test_a_controller_key_names_its_rig_run_and_its_fmu_design(key, name, design):
    """What nfal compare --port and nfal reproduce's rig runs share."""
    from nfal.models.comparison import controller_design, controller_name

    assert controller_name(key) == name
    assert controller_design(key) == design
