"""``fcmpc-predict``: before a mission, what this route and vehicle can reach.

    fcmpc-predict --params companion.parm                 # the route and settings of a .parm
    fcmpc-predict --param NAV_START_LAT=-40 --param NAV_START_LON=160 \\
                  --param NAV_DEST_LAT=-36 --param NAV_DEST_LON=168 --heading compass --no-ins

Prints the element set the navigator will measure for the declared heading source, the angle
between the elements' gradients along the route (a warning where they are nearly parallel: across
them the position is dead reckoning), and the predicted miss at arrival with its 95 % radius, from
the navigator's own covariance along its own commands on a quiet day
(:mod:`companion.nav.prediction`). Exit 0; a user's mistake is one line and exit 2.
"""
from __future__ import annotations

import json
import sys
from dataclasses import asdict

from companion.cli import ArgumentParser, param_items, run_main
from companion.nav.prediction import predict_route
from companion.params import NavConfig, read_parm_file, validate_all

__all__ = ["main"]


def build_parser() -> ArgumentParser:
    parser = ArgumentParser(prog="fcmpc-predict", description=__doc__.split("\n")[0])
    parser.add_argument("--params", metavar="FILE", help="a .parm file overlaid on the defaults")
    parser.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                        help="override one parameter (repeatable)")
    parser.add_argument("--heading", choices=("compass", "independent"), default="compass",
                        help="where the flight controller's yaw comes from: its compass (ArduPilot's and PX4's "
                             "default: D is then no measurement) or an independent source; default compass")
    parser.add_argument("--no-ins", action="store_true",
                        help="no independent INS position: the navigator dead-reckons between fixes")
    parser.add_argument("--json", action="store_true", help="print the prediction as JSON")
    return parser


def _run(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)
    values = read_parm_file(args.params) if args.params else {}
    values.update(param_items(args.param))
    config = NavConfig.from_values(validate_all(values))
    prediction = predict_route(config, compass_derived=args.heading == "compass", has_ins=not args.no_ins)
    if args.json:
        print(json.dumps({**asdict(prediction), "unobservable": prediction.unobservable}, default=float))
    else:
        print("\n".join(prediction.lines()))
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_main("fcmpc-predict", lambda: _run(argv))


if __name__ == "__main__":
    sys.exit(main())
