"""``fcmpc-replay``: the command line of the evaluation (a user error is one line, exit 2)."""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from companion.io.sensors.base import SensorError
from companion.io.sensors.replay import sniff_log_format
import replay
from replay.evaluate import DEFAULT_WINDOWS_S, evaluate
from replay.outputs import write_outputs
from replay.report import format_report

__all__ = ["main"]

def _windows(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"--window-s takes seconds separated by commas, got {text!r}") from err
    if not values or any(not (v > 0.0 and math.isfinite(v)) for v in values):
        raise argparse.ArgumentTypeError(f"--window-s needs positive seconds, got {text!r}")
    return values


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="fcmpc-replay", description=replay.__doc__.split("\n")[0])
    parser.add_argument("log", metavar="LOG", help="ArduPilot DataFlash .bin or MAVLink .tlog")
    parser.add_argument("--model", default=None,
                        help="WMM2010|WMM2015|WMM2015V2|WMM2020|WMM2025 or a .COF path (default: by the log's date)")
    parser.add_argument("--window-s", type=_windows, default=DEFAULT_WINDOWS_S,
                        help="averaging windows in seconds, comma separated (default 1,10,30)")
    parser.add_argument("--out", default=None, help="output folder (default out/replay/<log stem>)")
    parser.add_argument("--mag-instance", type=int, default=0, help="magnetometer instance (default 0, the primary)")
    parser.add_argument("--prior-offset-km", type=float, default=10.0,
                        help="the fix's prior is the GPS position moved this far north-east (default 10)")
    parser.add_argument("--crash-guard-s", type=float, default=10.0,
                        help="the airborne span ends this long before a detected crash (default 10)")
    parser.add_argument("--no-plots", action="store_true")
    args = parser.parse_args(argv)
    try:
        sniff_log_format(args.log)
        ev = evaluate(args.log, args.model, args.window_s, args.prior_offset_km, args.crash_guard_s,
                      args.mag_instance)
    except (SensorError, ValueError, OSError) as err:
        print(f"fcmpc-replay: {err}", file=sys.stderr)
        return 2
    report = format_report(ev)
    print(report)
    out = Path(args.out) if args.out else Path("out") / "replay" / Path(args.log).stem
    written = write_outputs(ev, out, plots=not args.no_plots)
    print(f"written: {', '.join(str(p) for p in written)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
