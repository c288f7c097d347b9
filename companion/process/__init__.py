"""The companion process, in parts the application (:mod:`companion.process.companion`) builds and wires.

::

    options.py      AppOptions (the command line as data) and the process-wide constants
    mission_state.py MissionState: the mission's shared mutable state, one dataclass
    settings.py     the live configuration, rebuilt when a parameter changes
    voice.py        what the companion says: STATUSTEXT, stderr, the summary's events
    machine.py      the phase state machine: states, events and the transition table
    phases/         one class per phase (enter / run / exit) and the driver taking the table's transitions
    failsafe_response.py  health -> failsafe: enter, hold, recover (rules in companion.failsafe)
    mode_commands.py the mode commands sent and not yet confirmed: ours or the pilot's?
    operator_commands.py the operator's hold / resume / start (COMMAND_LONG to 191, COMMAND_ACK)
    intake.py       samples in: MAVLink and --sensors samples into the magnetometer pipeline
    preparation.py  start-up and mission preparation: start position, elements, calibration
    calibration_turn.py the magnetometer's calibration circles before the mission
    control_step.py one control step: the period into companion.nav.navigator, returned as a StepOutcome
    estimate.py     the navigator's position now (the trim, the feed, the operator's status read it)
    outputs.py      what leaves for the FC: heartbeat, stream requests, setpoints, the step's estimate
    telemetry.py    the position feed (GPS_INPUT / HIL_GPS) and the operator's status
    reporting.py    steps.csv rows; summary.py: summary.json
    status.py       --http: the status page's snapshot, handed to its server (companion.io.status_page)
    resume.py       the navigator's state saved every step; resume after a crash, or start from it
    mission_clock.py mission time = message time minus the pauses
    companion.py    CompanionApp: builds the parts, the receive hook, the periodic hooks and the run loop

Each part receives in its constructor, typed, the parts it uses (as a MAVProxy module gets its
narrow ``mpstate``), and returns results instead of calling back into the part that called it: the
control step returns its outcome to the running phase, a phase returns the transition it wants to
the driver (:class:`companion.process.phases.Phases`). What several parts share of the running
mission is the one :class:`~companion.process.mission_state.MissionState`. No part imports
:mod:`companion.process.companion` (tests/test_architecture.py checks both). The entry point
(``fcmpc-companion``, ``python -m companion.app``) is :mod:`companion.app`; nothing here imports it.
"""
