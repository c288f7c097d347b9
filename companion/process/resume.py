"""Resume after a crash (issue 10, item 7): the navigator's state saved atomically, read at start.

What is saved (``NavSnapshot``, pickled): the mission's id and number, the restarts so far, the
last command, the element set and start-up bias, where the mission clock stood (mission time
since the start, and the next step), and the navigation core's own state: estimate, fusion
filter (state and covariance), gradient estimate, phase, reference path -- the core's own
:meth:`Mission.snapshot <companion.nav.mission.Mission.snapshot>`, everything but the parts
:meth:`~companion.nav.mission.Mission.restore` rebuilds from its configuration (the field model
and the QP). Written at every control step, every ``SAVE_EVERY_S`` of message time while
running (so the time flown since the step is known), and at the end: to a temporary file in the
same folder, fsync, rename, so a kill at any instant leaves the old state or the new, never half.
The core's filters hold the field model too; a model shipped with the package is saved by its
name and read back as that same model (:func:`companion.nav.field.load_wmm`), so the file carries
the state and not 239 kB of constant coefficients and their precomputed tables (418 kB -> 180 kB
a step on the Pacific mission, the same state restored); any other model is saved whole.

At start, once the flight controller is heard (message time is the FC's time since boot, so
the age is judged on the clock the vehicle kept running while the companion was down):

* saved no more than ``RESUME_MAX_AGE_S`` ago, mission not finished: the mission is resumed at
  the step it was at (STATUSTEXT "resuming mission N ..."), without a new start-up average;
* older, or saved before an FC reboot (its clock went back): a new mission starts from the saved
  estimate ("last estimate"), never from NAV_START in mid-route;
* of a mission that had ended (arrived or failed): said; the next mission starts as configured;
* unreadable: said, and the start is the usual one (there is nothing to trust).

A flight-controller reboot under a running mission goes the same way as a resume, from memory
(:meth:`Resume.continue_after_reboot`): the mission is kept and goes on once re-engaged.
"""
from __future__ import annotations

import contextlib
import copyreg
import io
import math
import os
import pickle
import tempfile
import uuid
from dataclasses import dataclass
from pathlib import Path

from companion.io.link.clock import MessageClock
from companion.io.link import mavlink
from companion.nav.field import WorldMagneticModel, load_wmm
from companion.nav.mission import Command, Mission
from companion.process.mission_clock import MissionClock
from companion.process.mission_state import MissionState
from companion.process.reporting import Reporting
from companion.process.voice import Voice

__all__ = ["RESUME_MAX_AGE_S", "SAVE_EVERY_S", "NavSnapshot", "NavStateStore", "Resume", "dumps"]

RESUME_MAX_AGE_S = 300.0     # message time: the vehicle held this long at most (less than a control period)
SAVE_EVERY_S = 30.0          # message time between saves while running (besides every step)
SNAPSHOT_VERSION = 3          # 3: the estimator keeps the ring current's SYM-H reference; 2: the filter measures its noise
                              # (FUS_R_SRC). An older state is not resumed: its objects lack what this code reads


@dataclass(frozen=True)
class NavSnapshot:
    version: int
    mission_id: str
    mission_no: int
    restarts: int
    msg_time_s: float            # the FC's message time of the save
    elapsed_s: float             # mission time since the mission's start, at the save
    next_step_rel_s: float       # the next step, in mission time since the start
    command: Command
    elements_code: int
    bias: tuple[float, float] | None
    finished: bool
    mission_state: dict          # Mission.snapshot()

    def mission(self) -> Mission:
        """The core as it was (:meth:`Mission.restore`)."""
        return Mission.restore(self.mission_state)


def _reduce_model(model: WorldMagneticModel):
    """Pickle a shipped field model as the call that loads it (the same cached object at load);
    any other model (built from another file, extrapolating) as itself."""
    try:
        shipped = load_wmm(model.name) is model
    except ValueError:   # not a shipped model's name
        shipped = False
    return (load_wmm, (model.name,)) if shipped else model.__reduce_ex__(pickle.HIGHEST_PROTOCOL)


# The pickler's reductions: the default ones, and the field model's by name. A dispatch table is
# consulted only for that type (a persistent_id hook would be a Python call for every object).
_DISPATCH = {**copyreg.dispatch_table, WorldMagneticModel: _reduce_model}


def dumps(snapshot: NavSnapshot) -> bytes:
    """The snapshot's bytes as saved (``pickle.loads`` reads them back)."""
    buffer = io.BytesIO()
    pickler = pickle.Pickler(buffer, protocol=pickle.HIGHEST_PROTOCOL)
    pickler.dispatch_table = _DISPATCH
    pickler.dump(snapshot)
    return buffer.getvalue()


class NavStateStore:
    """One snapshot file, written atomically."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)

    def save(self, snapshot: NavSnapshot) -> None:
        data = dumps(snapshot)
        try:
            fd, tmp = self._temporary()
        except FileNotFoundError:   # the folder is not there (yet, or any more): make it, once per need
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = self._temporary()
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self.path)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise

    def _temporary(self) -> tuple[int, str]:
        return tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.parent)

    def load(self) -> tuple[NavSnapshot | None, str]:
        """(snapshot, "") / (None, "") when there is none / (None, why it is unusable)."""
        for stale in self.path.parent.glob(f".{self.path.name}.*.tmp"):   # a kill during a save
            with contextlib.suppress(OSError):
                stale.unlink()
        try:
            data = self.path.read_bytes()
        except FileNotFoundError:
            return None, ""
        except OSError as err:
            return None, f"cannot read {self.path}: {err.strerror or err}"
        try:
            snapshot = pickle.loads(data)   # our own file, written by this process's predecessor
        except Exception as err:  # noqa: BLE001 - any decoding failure means the same: unusable
            return None, f"{self.path} is unreadable ({type(err).__name__})"
        if not isinstance(snapshot, NavSnapshot) or snapshot.version != SNAPSHOT_VERSION:
            return None, f"{self.path} is not a navigator state of version {SNAPSHOT_VERSION}"
        return snapshot, ""


class Resume:
    """Saving while running, and judging the saved state at start."""

    def __init__(self, path: str | os.PathLike[str], state: MissionState, clock: MissionClock,
                 msg_clock: MessageClock, reporting: Reporting, voice: Voice) -> None:
        self.mission_state = state
        self.clock = clock
        self.msg_clock = msg_clock
        self.reporting = reporting
        self.voice = voice
        self.store = NavStateStore(path)
        self.saved, self.load_error = self.store.load()
        self.pending: NavSnapshot | None = None     # to resume when the vehicle is engaged
        self.pending_mission: Mission | None = None   # ... with this core, kept in memory (an FC reboot)
        self.mission_id = ""
        self.last_save_s = -math.inf
        self.resumed_from = ""                      # for the summary

    def new_mission(self) -> None:
        self.mission_id = uuid.uuid4().hex

    # ------------------------------------------------------------------ saving
    def snapshot(self, at_s: float, finished: bool = False) -> NavSnapshot:
        """The running mission as of message time ``at_s`` (a mission and a command exist)."""
        state = self.mission_state
        elapsed = self.clock.mission_time(at_s) - state.m0
        return NavSnapshot(SNAPSHOT_VERSION, self.mission_id, state.mission_no, state.restarts, at_s, elapsed,
                           state.next_step_m - state.m0, state.command, state.elements_code, state.bias, finished,
                           state.mission.snapshot())

    def save(self, finished: bool = False) -> None:
        if self.mission_state.mission is None or self.mission_state.command is None:
            return
        now = self.msg_clock.now_s
        snapshot = self.snapshot(now, finished)
        try:
            self.store.save(snapshot)
        except OSError as err:   # the mission goes on; say it once per failure kind
            self.voice.say(f"FcMPC: cannot save the navigator state: {err.strerror or err}"[:200],
                           mavlink.MAV_SEVERITY_WARNING)
        self.last_save_s = now

    def fc_rebooted(self) -> None:
        """The FC's old clock is void: a save is due at once."""
        self.last_save_s = -math.inf

    def maybe_save(self, now: float) -> None:
        if now - self.last_save_s >= SAVE_EVERY_S:
            self.save()

    # ------------------------------------------------------------------ at start
    def judge_saved(self) -> bool:
        """Once the FC is heard (in startup): resume (True: a mission is ``pending``), or start anew
        from the saved estimate."""
        snap, say = self.saved, self.voice.say
        self.saved = None
        if self.load_error:
            say(f"FcMPC: navigator state not used: {self.load_error}"[:200], mavlink.MAV_SEVERITY_WARNING)
            return False
        if snap is None:
            return False
        age = self.msg_clock.now_s - snap.msg_time_s
        cmd = snap.command
        if not snap.finished and 0.0 <= age <= RESUME_MAX_AGE_S:
            self.pending = snap
            say(f"FcMPC: resuming mission {snap.mission_no} at step {cmd.step} from the state saved "
                f"{age:.0f} s ago", mavlink.MAV_SEVERITY_NOTICE)
            return True
        if snap.finished:   # not in mid-route: the next mission starts as configured
            say(f"FcMPC: mission {snap.mission_no} of the saved state had ended", mavlink.MAV_SEVERITY_INFO)
            return False
        why = "saved before an FC reboot" if age < 0.0 else f"{age:.0f} s old (resume limit {RESUME_MAX_AGE_S:g} s)"
        if math.isfinite(cmd.est_lat_deg) and math.isfinite(cmd.est_lon_deg):
            self.mission_state.restart_from = (cmd.est_lat_deg, cmd.est_lon_deg)
            say(f"FcMPC: state of mission {snap.mission_no} {why}: new mission from its last estimate "
                f"{cmd.est_lat_deg:.4f},{cmd.est_lon_deg:.4f}"[:200], mavlink.MAV_SEVERITY_NOTICE)
        return False

    def continue_after_reboot(self, last_s: float) -> None:
        """The flight controller rebooted under the running mission: keep it (estimate, filter,
        gradient, step clock as of ``last_s``, the last message time on the FC's old clock) to go
        on with once the vehicle is engaged again, exactly as after a restart of our own."""
        self.pending = self.snapshot(last_s)
        self.pending_mission = self.mission_state.mission

    def resume_mission(self, now: float) -> None:
        """Entering RUNNING with the saved mission: no new start-up, the step clock where it stood."""
        state, snap = self.mission_state, self.pending
        self.pending = None
        live, self.pending_mission = self.pending_mission, None
        state.mission = live if live is not None else snap.mission()
        state.command = snap.command
        state.elements_code, state.bias = snap.elements_code, snap.bias
        state.mission_no, state.restarts = snap.mission_no, snap.restarts
        self.mission_id = snap.mission_id
        state.m0 = self.clock.mission_time(now) - snap.elapsed_s
        state.next_step_m = state.m0 + snap.next_step_rel_s
        state.last_phase = snap.command.phase
        self.resumed_from = f"mission {snap.mission_no} step {snap.command.step}"
        remaining = snap.command.remaining_m
        self.voice.say(f"FcMPC: mission {snap.mission_no} resumed at step {snap.command.step}, estimate "
                    f"{snap.command.est_lat_deg:.4f},{snap.command.est_lon_deg:.4f}"
                    + (f", {remaining / 1000.0:.1f} km to go" if math.isfinite(remaining) else ""))
        self.reporting.record_event("resume", self.resumed_from)
