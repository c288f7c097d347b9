"""MAVProxy module ``fcmpc``: the companion's state, commands and parameter help in the console,
and its estimate with the 95 % ellipse and the destination on the map (docs/mavproxy.md).

``fcmpc status``          phase, distance to go, the estimate's 1-sigma, space weather, failsafes
``fcmpc hold|resume``     MAV_CMD_DO_PAUSE_CONTINUE (0 / 1) to the companion's component
``fcmpc start``           MAV_CMD_MISSION_START to the companion's component
``fcmpc param|help NAME`` description, unit, range and default from the registry (a pattern lists)

What the companion's messages mean is read by :class:`companion.operator_status.StatusReader`,
the one reader of them; this module only prints and draws. It is multi-vehicle in MAVProxy's
sense so that it receives the companion's HEARTBEAT whatever component MAVProxy targets.
"""
from __future__ import annotations

import fnmatch
import math
import time
from dataclasses import dataclass

from MAVProxy.modules.lib import mp_module
from pymavlink import mavutil

from companion.operator_status import COMPANION_COMPONENT, DEST_PARAMS, FEED_PARAMS, StatusReader
from companion.registry import REGISTRY, SPEC_BY_NAME, ParamSpec
from fcmpc.mavproxy.ellipse import ellipse_axes, ellipse_points

__all__ = ["ELLIPSE_P", "MAP_KEYS", "MAP_LAYER", "FcmpcModule", "MapShape", "describe_param", "init",
           "map_shapes", "update_map"]

ELLIPSE_P = 0.95
PARAM_REFRESH_WALL_S = 10.0      # NAV_DEST_* and the feed's values asked for again this often
COMMANDS = {"hold": (mavutil.mavlink.MAV_CMD_DO_PAUSE_CONTINUE, 0.0),
            "resume": (mavutil.mavlink.MAV_CMD_DO_PAUSE_CONTINUE, 1.0),
            "start": (mavutil.mavlink.MAV_CMD_MISSION_START, 0.0)}
MAP_KEYS = ("fcmpc:ellipse", "fcmpc:estimate", "fcmpc:destination")
MAP_LAYER = "FcMPC"
USAGE = "usage: fcmpc <status|hold|resume|start|param NAME|help NAME>"


def describe_param(spec: ParamSpec, value: float | None = None) -> str:
    """One parameter for people: description, unit, range, default (and the companion's value)."""
    unit = f" {spec.unit}" if spec.unit else ""
    kind = "integer" if spec.kind is int else "real"
    now = f"; the companion has {value:g}{unit}" if value is not None and math.isfinite(value) else ""
    return (f"{spec.name}: {spec.doc}\n  unit: {spec.unit or '-'}; range [{spec.minimum:g}, {spec.maximum:g}]{unit}; "
            f"default {spec.default:g}{unit} ({kind}){now}")


@dataclass(frozen=True)
class MapShape:
    """What to draw, without the map's classes: ``kind`` 'polygon' (``points``) or 'icon' (``latlon``)."""

    key: str
    kind: str
    points: tuple[tuple[float, float], ...] = ()
    latlon: tuple[float, float] = (math.nan, math.nan)
    colour: tuple[int, int, int] = (255, 255, 255)
    icon: str = ""
    label: str = ""


def map_shapes(reader: StatusReader) -> list[MapShape]:
    """The estimate (with its 95 % ellipse when the covariance is known) and the destination."""
    shapes = []
    if reader.estimate is not None:
        lat, lon = reader.estimate
        try:
            axes = ellipse_axes(reader.cov_ne_m2, ELLIPSE_P)
            points = ellipse_points(lat, lon, reader.cov_ne_m2, ELLIPSE_P)
        except ValueError:   # no covariance yet (NaN): the estimate alone
            axes = None
        if axes is not None:
            shapes.append(MapShape(MAP_KEYS[0], "polygon", points=tuple(points), colour=(255, 0, 255)))
        label = "FcMPC" + (f" 95% {axes.semi_major_m:.0f} x {axes.semi_minor_m:.0f} m" if axes is not None else "")
        shapes.append(MapShape(MAP_KEYS[1], "icon", latlon=(lat, lon), icon="purpleplane.png", label=label))
    if reader.destination is not None:
        shapes.append(MapShape(MAP_KEYS[2], "icon", latlon=reader.destination, icon="flag.png",
                               label="FcMPC destination"))
    return shapes


def _slip_objects(shapes: list[MapShape], slipmap):
    """MAVProxy's slip objects for ``shapes`` (``slipmap``: the map module's ``map``). They come from
    mp_slipmap_util, where they are defined (mp_slipmap re-exports them but also imports wxPython)."""
    from MAVProxy.modules.mavproxy_map import mp_slipmap_util   # needs OpenCV: only with a map loaded

    for shape in shapes:
        if shape.kind == "polygon":
            yield mp_slipmap_util.SlipPolygon(shape.key, list(shape.points), layer=MAP_LAYER, colour=shape.colour,
                                              linewidth=2, showcircles=False)
        else:
            yield mp_slipmap_util.SlipIcon(shape.key, shape.latlon, slipmap.icon(shape.icon), layer=MAP_LAYER,
                                           label=shape.label, colour=shape.colour)


def update_map(slipmap, shapes: tuple[MapShape, ...], before: tuple[MapShape, ...] = ()) -> None:
    """Show ``shapes`` on ``slipmap`` (MAVProxy's MPSlipMap: an object added under a key it already
    shows replaces it) and take away those of ``before`` that ``shapes`` no longer has (the ellipse
    once the covariance is unknown)."""
    for key in sorted({s.key for s in before} - {s.key for s in shapes}):
        slipmap.remove_object(key)
    for obj in _slip_objects(list(shapes), slipmap):
        slipmap.add_object(obj)


class FcmpcModule(mp_module.MPModule):
    def __init__(self, mpstate) -> None:
        super().__init__(mpstate, "fcmpc", "Fc-MPC companion: status, hold/resume/start, parameter help, map",
                         multi_vehicle=True)
        self.reader = StatusReader(system=self.target_system or 1, component=COMPANION_COMPONENT)
        self.pending: dict[int, str] = {}     # command -> the word typed, until its COMMAND_ACK
        self.next_param_request = 0.0
        self.drawn: dict[str, tuple] = {}   # map module's name -> (its map, the shapes it shows)
        self.reported: tuple = ()
        self.shapes: tuple[MapShape, ...] = ()
        self.add_command("fcmpc", self.cmd_fcmpc, "Fc-MPC companion",
                         ["<status|hold|resume|start>", "<param|help> (FCMPCPARAM)"])
        self.add_completion_function("(FCMPCPARAM)", lambda text: [s.name for s in REGISTRY])

    # ------------------------------------------------------------------ MAVProxy's hooks
    def mavlink_packet(self, msg) -> None:
        self.reader.system = self.target_system or 1   # the companion is on the vehicle MAVProxy targets
        if msg.get_srcSystem() != self.reader.system or msg.get_srcComponent() != self.reader.component:
            return
        if msg.get_type() == "COMMAND_ACK" and msg.command in self.pending:
            result = mavutil.mavlink.enums["MAV_RESULT"].get(msg.result)
            name = result.name.replace("MAV_RESULT_", "") if result is not None else str(msg.result)
            print(f"fcmpc: {self.pending.pop(msg.command)}: {name} by the companion")
        self.reader.packet(msg, time.monotonic())

    def idle_task(self) -> None:
        now = time.monotonic()
        if math.isfinite(self.reader.heard_wall_s) and now >= self.next_param_request:
            self.next_param_request = now + PARAM_REFRESH_WALL_S
            self.request_params()
        self.draw()

    def unload(self) -> None:
        for mod in self.module_matching("map*"):
            for key in MAP_KEYS:
                mod.map.remove_object(key)
        self.drawn.clear()
        self.remove_command("fcmpc")
        super().unload()

    # ------------------------------------------------------------------ the command
    def cmd_fcmpc(self, args: list[str]) -> None:
        if not args:
            print(USAGE)
        elif args[0] == "status":
            for line in self.reader.lines(time.monotonic()):
                print(line)
            self.request_params()
        elif args[0] in COMMANDS:
            self.send_command(args[0])
        elif args[0] in ("param", "help"):
            self.cmd_param(args[1:])
        else:
            print(USAGE)

    def cmd_param(self, args: list[str]) -> None:
        if not args:
            print("fcmpc: parameters: " + " ".join(spec.name for spec in REGISTRY))
            return
        pattern = args[0].upper()
        spec = SPEC_BY_NAME.get(pattern)
        if spec is not None:
            print(describe_param(spec, self.reader.params.get(spec.name)))
            return
        found = [s for s in REGISTRY if fnmatch.fnmatchcase(s.name, pattern) or pattern in s.name]
        if not found:
            print(f"fcmpc: no parameter {args[0]!r} (fcmpc param lists them)")
        for s in found:
            print(f"{s.name:16s} [{s.minimum:g}, {s.maximum:g}] {s.unit or '-':6s} {s.doc[:80]}")

    def send_command(self, word: str) -> None:
        command, param1 = COMMANDS[word]
        master = self.master
        if master is None:
            print("fcmpc: no link")
            return
        self.pending[command] = word
        master.mav.command_long_send(self.reader.system, self.reader.component, command, 0, param1,
                                     0, 0, 0, 0, 0, 0)

    def request_params(self) -> None:
        master = self.master
        if master is None:
            return
        for name in DEST_PARAMS + FEED_PARAMS:
            master.mav.param_request_read_send(self.reader.system, self.reader.component, name.encode("ascii"), -1)

    # ------------------------------------------------------------------ the map
    def draw(self) -> None:
        """Each map module shows the latest shapes: re-drawn when they change, and in full on a map
        loaded (or re-loaded) after the module."""
        maps = self.module_matching("map*")
        if not maps:
            return
        reported = (self.reader.estimate, self.reader.cov_ne_m2, self.reader.destination)
        if reported != self.reported:       # idle_task runs at hundreds of Hz; the status changes at 1 Hz
            self.reported, self.shapes = reported, tuple(map_shapes(self.reader))
        shapes = self.shapes
        for mod in maps:
            slipmap, before = self.drawn.get(mod.name, (None, ()))
            if slipmap is mod.map and before == shapes:
                continue
            update_map(mod.map, shapes, before if slipmap is mod.map else ())
            self.drawn[mod.name] = (mod.map, shapes)


def init(mpstate) -> FcmpcModule:
    """MAVProxy's entry point (``module load fcmpc``)."""
    return FcmpcModule(mpstate)
