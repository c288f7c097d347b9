"""The companion process, in parts the application (:mod:`companion.process.companion`) wires together.

::

    options.py      AppOptions (the command line as data) and the process-wide constants
    machine.py      the phase state machine: states, events and the transition table
    phases.py       what each phase does on a control tick, and the transitions' actions
    failsafe_response.py  health -> failsafe: enter, hold, recover (rules in companion.failsafe)
    mode_commands.py the mode commands sent and not yet confirmed: ours or the pilot's?
    operator_commands.py the operator's hold / resume / start (COMMAND_LONG to 191, COMMAND_ACK)
    intake.py       samples in: MAVLink and --sensors samples into the magnetometer pipeline
    preparation.py  start-up and mission preparation: start position, elements, calibration
    control_step.py one control step: the period into companion.nav.navigator, its verdict said, the command checked; the INS position
    outputs.py      what leaves: STATUSTEXT, heartbeat, setpoints, estimates, GPS_INPUT feed
    reporting.py    steps.csv rows and summary.json
    status.py       --http: the status page's snapshot, handed to its server (companion.io.status_page)
    resume.py       the navigator's state saved every step; resume after a crash, or start from it
    mission_clock.py mission time = message time minus the pauses
    companion.py    CompanionApp: the receive hook, the periodic hooks and the run loop

Each part is built with a reference to the app (``app``) and reaches the shared state and the
other parts through it, as ArduPilot's mode objects reach the vehicle; the parts never import
:mod:`companion.process.companion` (no import circle, even for type hints). The entry point
(``fcmpc-companion``, ``python -m companion.app``) is :mod:`companion.app`; nothing here imports it.
"""
