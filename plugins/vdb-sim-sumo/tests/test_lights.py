"""Freezing a traffic light from SUMO's own program: the ego sees the scenario's colour, the rest of the
junction keeps a state SUMO generated for it."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st
from vdb_sim_sumo.lights import ego_colour, frozen_state

SIGNALS = "GgyrO"


@st.composite
def programs(draw):
    size = draw(st.integers(1, 16))
    phases = draw(st.lists(st.text(SIGNALS, min_size=size, max_size=size), min_size=1, max_size=6))
    ego = draw(st.lists(st.integers(0, size - 1), min_size=1, max_size=size, unique=True))
    return phases, ego


@given(programs(), st.sampled_from(["red", "yellow", "green"]))
def test_the_ego_sees_the_frozen_colour(program, colour):
    phases, ego = program
    state = frozen_state(phases, ego, colour)
    assert len(state) == len(phases[0])
    assert ego_colour(state, ego) == colour


@given(programs(), st.sampled_from(["red", "yellow", "green"]))
def test_the_other_links_keep_a_phase_of_the_program(program, colour):
    phases, ego = program
    state = frozen_state(phases, ego, colour)
    others = [i for i in range(len(state)) if i not in ego]
    assert any(all(state[i] == phase[i] for i in others) for phase in phases)


def test_red_takes_the_phase_where_the_cross_traffic_flows():
    # SUMO's program of the suite's T-junction (TL.1): links 4, 5 start on the ego's approach.
    phases = ["rrgGGgGrr", "rrgGGgrrr", "rryyyyrrr", "ggrrrrrGG", "ggrrrrrrr", "yyrrrrrrr"]
    assert frozen_state(phases, [4, 5], "red") == "ggrrrrrGG"
    assert frozen_state(phases, [4, 5], "green") == "rrgGGgGrr"
    assert frozen_state(phases, [4, 5], "yellow") == "rrgGyyGrr"
