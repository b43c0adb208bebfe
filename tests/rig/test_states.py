"""The state machine: explicit table, illegal transitions refused, every change reported."""

import pytest

from nmsid.rig.states import OUTPUT_STATES, TRANSITIONS, IllegalTransition, State, StateMachine


def test_every_state_has_a_row_and_finished_is_terminal():
    assert set(TRANSITIONS) == set(State)
    assert TRANSITIONS[State.FINISHED] == frozenset()
    # any non-terminal state can trip and finish
    for s in State:
        if s not in (State.FINISHED, State.TRIPPED):
            assert State.TRIPPED in TRANSITIONS[s] and State.FINISHED in TRANSITIONS[s]
    assert OUTPUT_STATES == {State.CALIBRATING, State.STIMULATING}


def test_output_never_resumes_from_tripped_without_rearm_state():
    # from tripped the only ways out are re-arm (armed / calibrating) or finished
    assert TRANSITIONS[State.TRIPPED] == {State.ARMED, State.CALIBRATING, State.FINISHED}
    assert State.STIMULATING not in TRANSITIONS[State.TRIPPED]
    assert State.STIMULATING not in TRANSITIONS[State.PAUSED]


def test_transitions_reported_and_illegal_refused():
    seen = []
    sm = StateMachine(lambda old, new, why: seen.append((old, new, why)))
    sm.to(State.CALIBRATING, "ramps")
    sm.to(State.ARMED)
    sm.to(State.ARMED)  # no-op, not reported
    with pytest.raises(IllegalTransition, match="armed -> resting.*may go to"):
        sm.to(State.RESTING)
    assert sm.state is State.ARMED
    assert seen == [(State.IDLE, State.CALIBRATING, "ramps"),
                    (State.CALIBRATING, State.ARMED, "")]
    sm.to(State.FINISHED)
    with pytest.raises(IllegalTransition, match="none"):
        sm.to(State.IDLE)
