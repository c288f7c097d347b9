"""MAVProxy's map without its window, for tests: a MAVProxy module named ``map``
(``module load tests.fcmpc_mavproxy.headless_map``).

MAVProxy's own map module cannot load without a display: ``module load map`` fails with "No module
named 'wx'" (mavproxy_map/mp_slipmap.py imports lib/win_layout.py, which imports wxPython), and
with wxPython its MPSlipMap runs a wx.App in a child process, which needs a display. Other modules
reach the map only through ``module_matching('map*')`` and its ``map``'s ``add_object``,
``remove_object`` and ``icon``. This module offers exactly those and does with the objects what the
map's window does (mp_slipmap_ui.MPSlipMapFrame ``on_idle``, ``redraw_map``, ``draw_objects``):
objects arrive pickled (the real map sends them to its window's process through a multiprocessing
queue); one replaces the object of its key in its layer; a removal takes the key from every layer;
a redraw draws the layers in sorted order, each object whose bounds overlap the view's with the
object's own ``draw(img, pixmapper, bounds)``, the pixmapper being the map's Web Mercator
(mp_tile.MPTile.coord_to_pixel from the view's top-left corner). No tiles: the image is black.

Console: ``hmap view LAT LON GROUND_WIDTH_M`` centres an 800 x 600 view on LAT, LON with that width
on the ground there; ``hmap fit KEY OUTLINE`` centres it on object KEY, 8 times as wide as the
farthest point of polygon OUTLINE from it (the polygon across a quarter of the view, whatever the
objects are when the command runs); ``hmap save PATH`` draws the view and writes ``PATH.npy`` (the RGB image) and
``PATH.json`` (the view, the objects, the GLOBAL_POSITION_INT_COV messages heard from component
191). Each change prints ``hmap: added KEY at LAT,LON`` or ``hmap: removed KEY``.
"""
from __future__ import annotations

import json
import math
import pickle
from dataclasses import asdict, dataclass

import numpy as np
from MAVProxy.modules.lib import mp_module, mp_util
from MAVProxy.modules.mavproxy_map import mp_slipmap_util, mp_tile

__all__ = ["HeadlessSlipMap", "View", "init"]

COMPANION = 191


@dataclass(frozen=True)
class View:
    """The map window's view as mp_slipmap_ui keeps it: top-left corner, pixels, ground width (m) at
    the top-left corner's latitude."""

    lat: float
    lon: float
    width: int
    height: int
    ground_width: float

    @classmethod
    def centred(cls, tiles: mp_tile.MPTile, lat: float, lon: float, ground_width_m: float, width: int = 800,
                height: int = 600) -> View:
        """``ground_width_m`` across the view at ``lat``; the scale is Web Mercator's, the same
        (pixel width at the equator) at the top-left corner."""
        equator_px_m = ground_width_m / width / math.cos(math.radians(lat))
        top, left = tiles.coord_from_area(-width / 2.0, -height / 2.0, lat, lon, width, ground_width_m)
        return cls(top, left, width, height, equator_px_m * width * math.cos(math.radians(top)))

    def pixmapper(self, tiles: mp_tile.MPTile):
        """(lat, lon) -> (x, y) pixels, as MPSlipMapPanel.pixel_coords."""
        return lambda latlon: tiles.coord_to_pixel(self.lat, self.lon, self.width, self.ground_width, latlon[0],
                                                   latlon[1])

    def bounds(self, tiles: mp_tile.MPTile) -> tuple[float, float, float, float]:
        """As redraw_map: (bottom latitude, left longitude, height in degrees, width in degrees)."""
        lat2, lon2 = tiles.coord_from_area(self.width - 1, self.height - 1, self.lat, self.lon, self.width,
                                           self.ground_width)
        return (lat2, self.lon, self.lat - lat2, mp_util.wrap_180(lon2 - self.lon))


class HeadlessSlipMap:
    """What MPSlipMap and its window do with slip objects, without the window."""

    def __init__(self, tile_cache: str, log=print) -> None:
        self.layers: dict[str, dict[str, object]] = {}
        self.tiles = mp_tile.MPTile(cache_path=tile_cache, download=False)
        self.log = log

    def add_object(self, obj) -> None:
        obj = pickle.loads(pickle.dumps(obj))          # the real map's queue to its window pickles
        self.layers.setdefault(obj.layer, {})[obj.key] = obj
        latlon = getattr(obj, "latlon", None) or obj.points[0]
        self.log(f"hmap: added {obj.key} at {latlon[0]:.7f},{latlon[1]:.7f}")

    def remove_object(self, key: str) -> None:
        for layer in self.layers.values():
            layer.pop(key, None)
        self.log(f"hmap: removed {key}")

    def icon(self, filename: str):
        return mp_tile.mp_icon(filename)                # MPSlipMap.icon

    def objects(self) -> dict[str, object]:
        return {key: obj for layer in self.layers.values() for key, obj in layer.items()}

    def draw(self, view: View) -> np.ndarray:
        img = np.zeros((view.height, view.width, 3), np.uint8)
        pixmapper, bounds = view.pixmapper(self.tiles), view.bounds(self.tiles)
        for name in sorted(self.layers):
            layer = self.layers[name]
            for key in sorted(layer):
                obj = layer[key]
                own = obj.bounds()
                if own is None or mp_util.bounds_overlap(bounds, own):
                    obj.draw(img, pixmapper, bounds)
        return img


def _describe(obj) -> dict:
    if isinstance(obj, mp_slipmap_util.SlipPolygon):
        return {"type": "polygon", "layer": obj.layer, "points": [list(p[:2]) for p in obj.points],
                "colour": list(obj.colour), "linewidth": obj.linewidth}
    return {"type": type(obj).__name__, "layer": obj.layer, "latlon": list(obj.latlon), "label": obj.label}


class HeadlessMapModule(mp_module.MPModule):
    def __init__(self, mpstate) -> None:
        super().__init__(mpstate, "map", "map without a window (tests)", public=True, multi_vehicle=True)
        self.map = HeadlessSlipMap(tile_cache="tiles")
        self.view = View.centred(self.map.tiles, -35.362938, 149.165085, 1000.0)     # MPSlipMap's defaults
        self.heard: list[dict] = []
        self.add_command("hmap", self.cmd_hmap, "headless map", ["<view|fit|save>"])

    def mavlink_packet(self, msg) -> None:
        if msg.get_type() == "GLOBAL_POSITION_INT_COV" and msg.get_srcComponent() == COMPANION:
            self.heard.append({"lat": msg.lat, "lon": msg.lon, "covariance": list(msg.covariance[:8])})
            del self.heard[:-50]

    def cmd_hmap(self, args: list[str]) -> None:
        objects = self.map.objects()
        if len(args) == 4 and args[0] == "view":
            self.view = View.centred(self.map.tiles, float(args[1]), float(args[2]), float(args[3]))
        elif len(args) == 3 and args[0] == "fit" and args[1] in objects and args[2] in objects:
            lat, lon = objects[args[1]].latlon
            reach = max(mp_util.gps_distance(lat, lon, p[0], p[1]) for p in objects[args[2]].points)
            self.view = View.centred(self.map.tiles, lat, lon, 8.0 * reach)
        elif len(args) == 2 and args[0] == "save":
            np.save(args[1] + ".npy", self.map.draw(self.view))
            record = {"view": asdict(self.view), "heard": self.heard,
                      "objects": {key: _describe(obj) for key, obj in self.map.objects().items()}}
            with open(args[1] + ".json", "w", encoding="utf-8") as out:
                json.dump(record, out, allow_nan=True)
            print(f"hmap: saved {args[1]}")
        else:
            print("usage: hmap view LAT LON GROUND_WIDTH_M | hmap fit KEY OUTLINE | hmap save PATH")

    def unload(self) -> None:
        self.remove_command("hmap")
        super().unload()


def init(mpstate) -> HeadlessMapModule:
    return HeadlessMapModule(mpstate)
