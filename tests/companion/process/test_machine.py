"""The phase state machine: the table is complete, closed, and the only way phases change."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

from companion.process.machine import (
    STATE_CODES,
    TRANSITIONS,
    Event,
    IllegalTransition,
    PhaseMachine,
    State,
    to_dot,
)

PHASES = {v for k, v in vars(State).items() if k.isupper()}
EVENTS = {v for k, v in vars(Event).items() if k.isupper()}
PROCESS = Path(__file__).resolve().parents[3] / "companion" / "process"


def test_table_uses_only_declared_phases_and_events():
    for (src, event), dst in TRANSITIONS.items():
        assert src in PHASES and dst in PHASES and event in EVENTS
    assert set(STATE_CODES) == PHASES
    assert len(set(STATE_CODES.values())) == len(PHASES)


def test_every_phase_is_reachable_and_done_is_final():
    reached, frontier = {State.WAIT_FC}, [State.WAIT_FC]
    while frontier:
        src = frontier.pop()
        for (a, _), b in TRANSITIONS.items():
            if a == src and b not in reached:
                reached.add(b)
                frontier.append(b)
    assert reached == PHASES
    assert not [key for key in TRANSITIONS if key[0] == State.DONE]


def test_a_whole_mission_with_a_restart():
    m = PhaseMachine()
    path = [m.fire(e) for e in (Event.FC_HEARD, Event.AVERAGED, Event.ENGAGED, Event.NAV_FAILED, Event.AVERAGED,
                                Event.ENGAGED, Event.ENDED)]
    assert path == [State.STARTUP, State.READY, State.RUNNING, State.STARTUP, State.READY, State.RUNNING, State.DONE]
    assert m.history[3] == (State.RUNNING, Event.NAV_FAILED, State.STARTUP)
    assert m.code(failsafe=False) == 5 and m.code(failsafe=True) == 4


@pytest.mark.parametrize("state", sorted(PHASES))
def test_events_without_a_transition_raise_and_change_nothing(state):
    for event in sorted(EVENTS):
        m = PhaseMachine(state)
        if (state, event) in TRANSITIONS:
            assert m.can(event)
            continue
        with pytest.raises(IllegalTransition, match=f"from {state} on {event}"):
            m.fire(event)
        assert m.state == state and not m.history


def test_dot_draws_every_edge():
    dot = to_dot()
    for (src, event), dst in TRANSITIONS.items():
        assert f'{src} -> {dst} [label="{event}"]' in dot


def test_only_the_machine_assigns_the_phase():
    """Every phase change goes through PhaseMachine.fire: no part writes ``machine.state``."""
    for path in sorted(PROCESS.rglob("*.py")):
        if path.name == "machine.py":
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.Assign, ast.AugAssign, ast.AnnAssign)):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                for target in targets:
                    assert not (isinstance(target, ast.Attribute) and target.attr == "state"), \
                        f"{path.name}:{node.lineno} assigns a phase outside the machine"
