"""The exchange order at a communication point (nfal.orchestration.schedule), without FMUs."""

from __future__ import annotations

import pytest
from helpers.properties import examples
from hypothesis import given
from hypothesis import strategies as st

from nfal.orchestration import AlgebraicLoopError
from nfal.orchestration.schedule import causal_sweep

FIG7_ELEMENTS = ("Plant", "Controller", "ResonanceTracker", "SensorChain")
FIG7_OUTPUTS = {"Plant": ["height", "velocity"], "Controller": ["drive_voltage", "excitation_command"],
                "ResonanceTracker": ["excitation_amplitude", "drive_frequency"], "SensorChain": ["measured_height"]}
FIG7_INPUTS = {"Plant": ["excitation_amplitude", "drive_frequency"], "Controller": ["reference", "measured_height"],
               "ResonanceTracker": ["drive_voltage"], "SensorChain": ["true_height"]}
FIG7_LINKS = [(("Controller", "drive_voltage"), ("ResonanceTracker", "drive_voltage")),
              (("ResonanceTracker", "excitation_amplitude"), ("Plant", "excitation_amplitude")),
              (("ResonanceTracker", "drive_frequency"), ("Plant", "drive_frequency")),
              (("Plant", "height"), ("SensorChain", "true_height")),
              (("SensorChain", "measured_height"), ("Controller", "measured_height"))]
FIG7_FEEDTHROUGH = {"Plant": {"height": (), "velocity": ()},
                    "Controller": {"drive_voltage": ("reference", "measured_height"),
                                   "excitation_command": ("reference", "measured_height")},
                    "ResonanceTracker": {"excitation_amplitude": ("drive_voltage",),
                                         "drive_frequency": ("drive_voltage",)},
                    "SensorChain": {"measured_height": ("true_height",)}}


def test_fig7_sweep_is_the_causal_chain_with_one_call_per_element_and_kind():
    order = [str(a) for a in causal_sweep(FIG7_ELEMENTS, FIG7_OUTPUTS, FIG7_INPUTS, FIG7_LINKS, FIG7_FEEDTHROUGH)]
    assert order == [
        "set Controller.reference",
        "get Plant.height, Plant.velocity",
        "set SensorChain.true_height",
        "get SensorChain.measured_height",
        "set Controller.measured_height",
        "get Controller.drive_voltage, Controller.excitation_command",
        "set ResonanceTracker.drive_voltage",
        "get ResonanceTracker.excitation_amplitude, ResonanceTracker.drive_frequency",
        "set Plant.excitation_amplitude, Plant.drive_frequency",
    ]


def test_variable_level_graph_orders_what_an_element_level_graph_could_not():
    # A.y depends on A.u (fed by B.z, no feedthrough); B.w depends on B.v (fed by A.y):
    # B -> A -> B at element level, but no algebraic loop.
    order = [str(a) for a in causal_sweep(
        ("A", "B"), {"A": ["y"], "B": ["z", "w"]}, {"A": ["u"], "B": ["v"]},
        [(("B", "z"), ("A", "u")), (("A", "y"), ("B", "v"))], {"A": {"y": ("u",)}, "B": {"z": (), "w": ("v",)}})]
    assert order == ["get B.z", "set A.u", "get A.y", "set B.v", "get B.w"]


@pytest.mark.parametrize("ring", [2, 3, 5])
def test_a_ring_of_feedthrough_blocks_is_an_algebraic_loop_named_in_flow_order(ring):
    names = [f"G{i}" for i in range(ring)]
    links = [((names[i], "y"), (names[(i + 1) % ring], "u")) for i in range(ring)]
    with pytest.raises(AlgebraicLoopError) as caught:
        causal_sweep(names, {n: ["y"] for n in names}, {n: ["u"] for n in names}, links,
                     {n: {"y": ("u",)} for n in names})
    loop = caught.value.variables
    assert len(loop) == 2 * ring and set(loop) == {f"{n}.{v}" for n in names for v in ("y", "u")}
    for i, variable in enumerate(loop):  # y -> next u -> its y ...
        following = loop[(i + 1) % len(loop)]
        element, name = variable.split(".")
        if name == "y":
            assert following == f"{names[(names.index(element) + 1) % ring]}.u"
        else:
            assert following == f"{element}.y"


def test_the_loop_is_named_even_with_a_tail_hanging_off_it():
    links = [(("A", "y"), ("B", "u")), (("B", "y"), ("A", "u")), (("B", "y"), ("C", "u"))]
    with pytest.raises(AlgebraicLoopError) as caught:
        causal_sweep(("C", "A", "B"), {e: ["y"] for e in "ABC"}, {e: ["u"] for e in "ABC"}, links,
                     {e: {"y": ("u",)} for e in "ABC"})
    assert set(caught.value.variables) == {"A.y", "B.u", "B.y", "A.u"}


@examples(60)
@given(st.integers(2, 6).flatmap(lambda n: st.tuples(
    st.just(n), st.lists(st.tuples(st.integers(0, n - 1), st.integers(0, n - 1)), max_size=8),
    st.lists(st.booleans(), min_size=n, max_size=n))))
def test_every_sweep_is_causal(case):
    """Random wiring: an algebraic loop reported is a cycle; otherwise every input is set after its source is read,
    every feedthrough output is read after its inputs are set, and every variable appears once."""
    n, wires, feedthrough_flags = case
    names = [f"E{i}" for i in range(n)]
    links = [((names[a], "y"), (names[b], f"u{k}")) for k, (a, b) in enumerate(wires)]
    inputs = {e: [v for (_, _), (t, v) in links if t == e] for e in names}
    feedthrough = {e: {"y": tuple(inputs[e]) if flag else ()} for e, flag in zip(names, feedthrough_flags)}
    try:
        actions = causal_sweep(names, {e: ["y"] for e in names}, inputs, links, feedthrough)
    except AlgebraicLoopError as exc:  # then what it reports must be a real cycle of the graph
        edges = {(f"{s}.{o}", f"{t}.{v}") for (s, o), (t, v) in links}
        edges |= {(f"{e}.{v}", f"{e}.y") for e in names for v in feedthrough[e]["y"]}
        loop = exc.variables
        assert loop and all((loop[i], loop[(i + 1) % len(loop)]) in edges for i in range(len(loop)))
        return
    position = {}
    for index, action in enumerate(actions):
        for variable in action.variables:
            assert (action.kind, action.element, variable) not in position
            position[(action.kind, action.element, variable)] = index
    assert len(position) == n + len(links)
    for (source, output), (target, variable) in links:
        assert position[("get", source, output)] < position[("set", target, variable)]
    for element in names:
        for variable in feedthrough[element]["y"]:
            assert position[("set", element, variable)] < position[("get", element, "y")]
