"""The result of one closed-loop mission, whichever simulator or firmware flew it.

Inputs are a truth track (time, lat, lon of the vehicle, from the simulator's truth log) and
the companion's ``steps.csv``; nothing here knows which process produced them, so a run on
ArduPilot or PX4 firmware is evaluated by the same functions as one on ``fcmpc-sitl``.

Three distances to the destination, kept apart because they answer different questions:

``rest_remaining_m``
    where the vehicle came to rest after the mission ended: the headline, what a user standing
    at the destination would measure. Taken from the truth track after the last control step,
    once the vehicle moved less than :data:`REST_TOL_M` over :data:`REST_WINDOW_S`; if the
    track ends while it still moves, the last point and ``came_to_rest = False``. A boat in a
    current drifts once stopped: where the simulator logs the speed through the water, the vehicle
    is at rest from the first sample after the last step at which that speed stayed below
    :data:`REST_SPEED_MPS` to the end of the track, and the miss is taken there (the drift after
    it is the water's, not the navigator's). The in-process Monte Carlo reports where its vehicle
    comes to rest the same way (``InProcessFlight.at_rest``: zero speed, no drift).
``step_remaining_m``
    the true distance at the last control step (the step that ended the mission).
``believed_remaining_m``
    what the companion believed at its last step (its estimate's distance to the destination,
    the number it compared with the arrival threshold).
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from companion.io.records import read_steps_csv
from companion.nav.geo import geodesic_distance_m
from sitl.truthlog import read_truth_csv

__all__ = ["REST_SPEED_MPS", "REST_TOL_M", "REST_WINDOW_S", "STATUS_EXIT", "TruthTrack", "FlyResult", "read_truth_track",
           "read_steps", "distances", "true_track", "result_json", "write_result", "summary_lines"]

REST_TOL_M = 2.0         # moved less than this over REST_WINDOW_S: at rest
REST_WINDOW_S = 10.0
REST_SPEED_MPS = 0.05    # speed through the water below this: stopped (drifting with the current at most)
# status -> exit code of fcmpc-fly
STATUS_EXIT = {"arrived": 0, "failed": 1, "error": 1, "timeout": 3, "interrupted": 130}


@dataclass(frozen=True)
class TruthTrack:
    """The vehicle's true track (any simulator): time since the start (s), WGS84 lat/lon (deg);
    optionally the flight controller's own solution (``fc_*``) for the plot, its boot time
    (``boot_s``, which an FC reboot restarts at 0; absent: the same as ``time_s``) and the speed
    through the water (``water_speed_mps``; absent where the simulator does not log it)."""

    time_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    fc_lat_deg: np.ndarray | None = None
    fc_lon_deg: np.ndarray | None = None
    boot_s: np.ndarray | None = None
    water_speed_mps: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.time_s)

    def index_at(self, time_s: float) -> int:
        """The index of the track's point nearest to the flight controller's message time ``time_s``
        (its boot time: after an FC reboot a message time occurs once per boot, and the latest is taken)."""
        clock = self.time_s if self.boot_s is None else self.boot_s
        gap = np.abs(clock - time_s)
        return int(np.flatnonzero(gap <= gap.min() + 1e-6)[-1])

    def position_at(self, time_s: float) -> tuple[float, float]:
        """The track's point at :meth:`index_at`."""
        index = self.index_at(time_s)
        return float(self.lat_deg[index]), float(self.lon_deg[index])


def read_truth_track(path: str | Path) -> TruthTrack | None:
    """A ``truth.csv`` of :mod:`sitl.truthlog` as a :class:`TruthTrack`; None if absent or empty."""
    path = Path(path)
    if not path.is_file():
        return None
    columns = read_truth_csv(path)
    if not columns.get("time_s"):
        return None
    fc_lat, fc_lon = columns.get("fc_lat_deg"), columns.get("fc_lon_deg")
    fc = fc_lat is not None and fc_lon is not None
    boot, water = columns.get("boot_s"), columns.get("speed_mps")
    return TruthTrack(np.asarray(columns["time_s"]), np.asarray(columns["lat_deg"]), np.asarray(columns["lon_deg"]),
                      np.asarray(fc_lat) if fc else None, np.asarray(fc_lon) if fc else None,
                      np.asarray(boot) if boot is not None else None,
                      np.asarray(water, float) if water is not None else None)


def read_steps(path: str | Path) -> list[dict]:
    """The control-step rows (``event == "step"``) of a companion's ``steps.csv``; [] if absent."""
    path = Path(path)
    return [row for row in read_steps_csv(path) if row["event"] == "step"] if path.is_file() else []


@dataclass(frozen=True)
class FlyResult:
    """One run; ``status`` is arrived | failed | timeout | interrupted | error."""

    status: str
    exit_code: int
    scenario: str
    seed: int
    iterations: int
    rest_remaining_m: float          # where the vehicle came to rest (the headline)
    step_remaining_m: float          # true distance at the last control step
    believed_remaining_m: float      # what the companion believed at its last step
    came_to_rest: bool
    wall_s: float
    sim_s: float
    out_dir: str
    plot_path: str | None
    dest_lat_deg: float
    dest_lon_deg: float
    mc_remaining_m: float = math.nan
    mc_iterations: int = 0
    companion: dict = field(default_factory=dict)
    message: str = ""
    controller: str = ""                       # NAV_CONTROLLER's name, as flown
    track_lat_deg: tuple[float, ...] = ()      # the true track at the start, each control step and at rest
    track_lon_deg: tuple[float, ...] = ()      # (:func:`true_track`: what fcmpc-montecarlo --fc measures)


def distances(truth: TruthTrack | None, steps: list[dict], dest: tuple[float, float]) -> dict:
    """``rest_remaining_m``, ``step_remaining_m``, ``believed_remaining_m``, ``came_to_rest``,
    ``iterations``, ``sim_s`` from a truth track and the companion's step rows (nan when unknown);
    ``rest_index``: the track's sample where the rest distance is taken (-1 without a track)."""
    out = {"rest_remaining_m": math.nan, "step_remaining_m": math.nan, "believed_remaining_m": math.nan,
           "came_to_rest": False, "iterations": 0, "sim_s": math.nan, "rest_index": -1}
    if steps:
        out["iterations"] = int(steps[-1]["step"])
        out["believed_remaining_m"] = float(steps[-1]["remaining_m"])
    if truth is None or len(truth) == 0:
        return out
    t = truth.time_s
    out["sim_s"] = float(t[-1])
    if steps:
        out["step_remaining_m"] = geodesic_distance_m(*truth.position_at(steps[-1]["msg_time_s"]), *dest)
    last = len(t) - 1
    stopped = _stopped_in_the_water(truth, steps)
    if stopped is not None:
        out["came_to_rest"], out["rest_index"] = True, stopped
        out["rest_remaining_m"] = geodesic_distance_m(truth.lat_deg[stopped], truth.lon_deg[stopped], *dest)
        return out
    first = int(np.searchsorted(t, t[-1] - REST_WINDOW_S, side="right")) - 1   # the window spans REST_WINDOW_S
    if first >= 0:
        moved = max(geodesic_distance_m(truth.lat_deg[i], truth.lon_deg[i], truth.lat_deg[last],
                                        truth.lon_deg[last]) for i in range(first, last + 1))
        out["came_to_rest"] = bool(moved < REST_TOL_M)
    out["rest_remaining_m"] = geodesic_distance_m(truth.lat_deg[last], truth.lon_deg[last], *dest)
    out["rest_index"] = last
    return out


def true_track(truth: TruthTrack | None, steps: list[dict], start: tuple[float, float],
               rest_index: int) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The true (lat, lon) at the start, at each control step and at ``rest_index`` (of
    :func:`distances`), as an in-process run's track is measured; the start alone without a track."""
    points = [start]
    if truth is not None and len(truth) > 0:
        points += [truth.position_at(float(s["msg_time_s"])) for s in steps]
        points.append((float(truth.lat_deg[rest_index]), float(truth.lon_deg[rest_index])))
    return tuple(float(p[0]) for p in points), tuple(float(p[1]) for p in points)


def _stopped_in_the_water(truth: TruthTrack, steps: list[dict]) -> int | None:
    """Index of the first sample after the last step from which the speed through the water stays
    below :data:`REST_SPEED_MPS` to the end of the track (for at least :data:`REST_WINDOW_S`);
    None when the track does not log that speed or the vehicle was still propelled at its end."""
    speed = truth.water_speed_mps
    if speed is None or not steps or len(speed) != len(truth):
        return None
    after = truth.index_at(steps[-1]["msg_time_s"])
    moving = np.flatnonzero(~(speed[after:] < REST_SPEED_MPS))
    index = after if len(moving) == 0 else after + int(moving[-1]) + 1
    if index > len(speed) - 1 or truth.time_s[-1] - truth.time_s[index] < REST_WINDOW_S:
        return None
    return index


def result_json(result: FlyResult) -> str:
    """The result as JSON text (nan written as null)."""
    data = {key: (None if isinstance(value, float) and not math.isfinite(value) else value)
            for key, value in asdict(result).items()}
    return json.dumps(data, indent=1, default=str) + "\n"


def write_result(out_dir: str | Path, result: FlyResult) -> Path:
    """``result.json`` in ``out_dir``."""
    path = Path(out_dir) / "result.json"
    path.write_text(result_json(result), encoding="utf-8")
    return path


def _km(metres: float) -> str:
    if not math.isfinite(metres):
        return "unknown"
    return f"{metres:.0f} m" if metres < 10_000.0 else f"{metres / 1000.0:.1f} km"


def summary_lines(result: FlyResult) -> list[str]:
    """What ``fcmpc-fly`` prints: the headline first, then the other two distances, plot and records."""
    sim_h = f"{result.sim_s / 3600.0:.2f} h simulated" if math.isfinite(result.sim_s) else "no simulated time"
    timing = f"{result.iterations} steps, {sim_h}, {result.wall_s:.1f} s wall"
    rest = _km(result.rest_remaining_m)
    where = "came to rest" if result.came_to_rest else "was last seen (still moving)"
    if result.status == "arrived":
        head = f"arrived: the vehicle {where} {rest} from the destination ({timing})"
    else:
        what = {"interrupted": "interrupted", "timeout": "timed out", "failed": "mission failed"}.get(
            result.status, "error")
        head = f"{what} before arriving: the vehicle {where} {rest} from the destination ({timing})"
    lines = [head,
             f"  at the last control step: {_km(result.step_remaining_m)} from the destination (true position)",
             f"  the companion believed:   {_km(result.believed_remaining_m)} to go"]
    if math.isfinite(result.mc_remaining_m):
        lines.append(f"  in-process Monte Carlo, same seed: {_km(result.mc_remaining_m)} at rest, "
                     f"{result.mc_iterations} steps")
    if result.plot_path:
        lines.append(f"  track plot: {result.plot_path}")
    lines.append(f"  records:    {result.out_dir}")
    if result.message:
        lines.append(f"  note: {result.message}")
    return lines
