"""``fcmpc-replay``: the command line of the evaluation (a user error is one line, exit 2)."""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from companion.io.sensors.base import SensorError
from fcmpc.replay.evaluate import DEFAULT_WINDOWS_S
from fcmpc.replay.calibrate import ALIGN_AXES
from fcmpc.replay.logeval import CALIBRATION_FITS, evaluate_log
from fcmpc.replay.outputs import write_outputs
from fcmpc.replay.report import format_log_report, format_report

__all__ = ["main"]

DESCRIPTION = ("Measured-data evaluation like the paper's Table 8: a recorded flight log replayed open-loop "
               "against its own GPS.")

def _windows(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"--window-s takes seconds separated by commas, got {text!r}") from err
    if not values or any(not (v > 0.0 and math.isfinite(v)) for v in values):
        raise argparse.ArgumentTypeError(f"--window-s needs positive seconds, got {text!r}")
    return values


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="fcmpc-replay", description=DESCRIPTION)
    parser.add_argument("log", metavar="LOG",
                        help="ArduPilot DataFlash .bin, MAVLink .tlog, PX4 .ulg or a .csv (columns in the README)")
    parser.add_argument("--model", default=None,
                        help="WMM2010|WMM2015|WMM2015V2|WMM2020|WMM2025 or a .COF path (default: by the log's date)")
    parser.add_argument("--date", default=None, metavar="YYYY-MM-DD",
                        help="the date of a log that carries none (default: from the log, which says its source)")
    parser.add_argument("--window-s", type=_windows, default=DEFAULT_WINDOWS_S,
                        help="averaging windows in seconds, comma separated (default 1,10,30)")
    parser.add_argument("--out", default=None, help="output folder (default out/replay/<log stem>)")
    parser.add_argument("--mag-instance", type=int, default=0, help="magnetometer instance (default 0, the primary)")
    parser.add_argument("--prior-offset-km", type=float, default=10.0,
                        help="the fix's prior is the GPS position moved this far north-east (default 10)")
    parser.add_argument("--crash-guard-s", type=float, default=10.0,
                        help="the airborne span ends this long before a detected crash (default 10)")
    parser.add_argument("--no-calibration", action="store_true",
                        help="replay the magnetometer as logged; by default its hard and soft iron and its alignment "
                             "(fcmpc-calibrate's fits) are fitted on each boot's first part and applied, and the fix "
                             "error is reported before and after on the rest of the boot only")
    parser.add_argument("--calibration-fit", choices=CALIBRATION_FITS, default="first-part",
                        help="first-part (default): fit on the boot's first part, judge on the rest; all-samples: "
                             "fit on every sample and judge the same samples (optimistic: the fit saw what it is "
                             "judged on)")
    parser.add_argument("--align", choices=ALIGN_AXES, default="xy",
                        help="the calibration's alignment to the body (fcmpc-calibrate --align; default xy)")
    parser.add_argument("--no-plots", action="store_true")
    args = parser.parse_args(argv)
    # A user error (unreadable or unsupported log, no date, a model that does not cover it) is one
    # line naming the file or option and exit code 2; anything else is a bug and keeps its traceback.
    try:
        result = evaluate_log(args.log, args.model, args.window_s, args.prior_offset_km, args.crash_guard_s,
                              args.mag_instance, args.date, calibrate=not args.no_calibration,
                              calibration_fit=args.calibration_fit, align=args.align)
    except (SensorError, ValueError, OSError) as err:
        print(f"fcmpc-replay: {err}", file=sys.stderr)
        return 2
    out = Path(args.out) if args.out else Path("out") / "replay" / Path(args.log).stem
    if len(result.evaluations) == 1 and not result.skipped:
        report = format_report(result.evaluations[0])
        written = write_outputs(result.evaluations[0], out, plots=not args.no_plots)
    else:
        report = format_log_report(result)
        written = []
        for label, ev in zip(result.labels, result.evaluations):
            written += write_outputs(ev, out / label, plots=not args.no_plots)
        out.mkdir(parents=True, exist_ok=True)
        (out / "table.md").write_text(report)
        written.insert(0, out / "table.md")
    print(report)
    print(f"written: {', '.join(str(p) for p in written)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
