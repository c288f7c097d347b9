"""``fcmpc-calibrate LOG``: the magnetometer's hard and soft iron fitted from a recorded log.

    fcmpc-calibrate ../shared/data/logs/log171.bin
    fcmpc-calibrate flight.tlog --out params/ --model WMM2025

The log (``.bin``, ``.tlog``, ``.ulg`` or ``.csv``, read by :mod:`fcmpc.replay.reading`) gives the
magnetometer's body-frame samples and its GPS; the field's total intensity is the World Magnetic
Model's at the first 3D fix on the log's date (:mod:`fcmpc.replay.models`), and the fit is
:func:`companion.nav.calibration.fit_calibration`. It prints the fit and its quality and writes
two ``.parm`` files a ground station loads:

* ``companion-mag.parm``: the companion's ``MAG_OFS_*`` (mG, subtracted), ``MAG_SCALE_*`` and
  ``MAG_SOFT_*`` (the symmetric soft iron), for the field the companion receives (the one logged);
* ``ardupilot-compass.parm``: ArduPilot's ``COMPASS_OFS*`` / ``COMPASS_DIA*`` / ``COMPASS_ODI*``
  (mG, added; ``corrected = DIA/ODI matrix (raw + OFS)``). ArduPilot logs the field it already
  corrected: the log's own COMPASS_* values (DataFlash ``PARM``, tlog ``PARAM_VALUE``) are
  composed in; a log without them is taken as raw.

A boot whose samples cover too few directions for the full fit but whose heading went round a
full circle (a boat, a car) gets the level fit (:func:`~companion.nav.calibration.fit_level_calibration`,
with the log's roll and pitch and the model's horizontal and vertical components); one with
neither is refused with the reasons (exit 2).

Then the magnetometer's alignment to the body (:func:`companion.nav.alignment.fit_alignment`): the
model's field direction at the GPS position of each sample, with the log's attitude, fits a small
rotation (``MAG_ROT_ROLL/PIT/YAW``, written to ``companion-mag.parm``); by default roll and pitch
only, from the inclination (``--align xyz`` also fits the yaw, for a yaw independent of this
compass; ``--align none`` skips it). A refused alignment is reported and the hard/soft iron still
written.
"""
from __future__ import annotations

import argparse
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from companion.io.sensors.base import SensorError
from companion.nav.calibration import (
    CalibrationFit,
    CalibrationRefused,
    ardupilot_compass_params,
    companion_params,
    down_in_body,
    fit_calibration,
    fit_level_calibration,
)
from companion.nav.alignment import AlignmentFit, aligned, alignment_params, fit_alignment
from companion.nav.magnetometer import MagCalibration
from companion.params import format_value, write_parm_file
from fcmpc.replay.logdata import CSV, ULOG, LogData
from fcmpc.replay.models import log_date, select_model
from fcmpc.replay.reading import read_boots, sniff_format
from fcmpc.replay.stats import interp_gps, wrap_pi

__all__ = ["ALIGN_AXES", "CALIBRATION_SHARES", "BootCalibration", "calibrate_boot", "calibrate_prefix",
           "fc_compass_values", "main"]

ALIGN_AXES = ("xy", "xyz", "none")
# fcmpc-replay's calibration span: the shortest of these shares of the boot (from its first 3D fix
# to its last magnetometer sample) whose fits are accepted; the fix error is judged after it
CALIBRATION_SHARES = (1.0 / 3.0, 0.4, 0.5, 0.6, 2.0 / 3.0)
# the alignment is fitted on samples with roll and pitch within this: in flips and crashes the
# logged attitude lags the magnetometer by more than the angles fitted
MAX_ALIGN_TILT_DEG = 30.0


@dataclass(frozen=True)
class BootCalibration:
    """A boot's hard/soft-iron fit (None if refused: ``refused`` says why), where its |B| came
    from, its alignment (None if refused or not asked: ``alignment_refused``) and the end of the
    samples they were fitted on (``until_s``, None: every sample of the boot)."""

    boot: int
    fit: CalibrationFit | None
    refused: str
    field_note: str
    alignment: AlignmentFit | None = None
    alignment_refused: str = ""
    until_s: float | None = None

    @property
    def accepted(self) -> int:
        """How many of the two fits were accepted (the hard/soft iron counts double)."""
        return 2 * (self.fit is not None) + (self.alignment is not None)

    @property
    def calibration(self) -> MagCalibration | None:
        """What the fits correct, composed (None when both were refused)."""
        if self.fit is None and self.alignment is None:
            return None
        base = self.fit.calibration if self.fit is not None else MagCalibration()
        return aligned(base, self.alignment.rotation_deg) if self.alignment is not None else base

    def describe(self) -> str:
        lines = [self.fit.describe() if self.fit else f"hard/soft iron not fitted: {self.refused.splitlines()[0]}"]
        if self.alignment is not None:
            lines.append(self.alignment.describe())
        elif self.alignment_refused:
            lines.append(f"alignment not fitted: {self.alignment_refused.splitlines()[0]}")
        return "\n".join(lines)


def calibrate_boot(data: LogData, model_spec: str | None = None, date: str | None = None,
                   until_s: float | None = None, align: str = "xy") -> BootCalibration:
    """Fit the boot's magnetometer (its samples from the first 3D fix to ``until_s``, all if None)
    against the model's |B| at its first 3D fix, then its alignment (``align``: one of
    :data:`ALIGN_AXES`) against the model's direction at each sample's GPS position (ValueError
    when the boot has no fix or no date; a refusal is returned, not raised)."""
    if len(data.gps) == 0:
        raise ValueError(f"boot {data.boot + 1}: no 3D GPS fix: the model's |B| needs the position")
    if align not in ALIGN_AXES:
        raise ValueError(f"align must be one of {', '.join(ALIGN_AXES)}, got {align!r}")
    when = log_date(data, date)
    model, model_note = select_model(model_spec, when)
    lat, lon, alt = (float(v) for v in data.gps[0, 1:4])
    field = model.elements(lat, lon, alt, when.decimal_year)
    field_nt = float(field.f_nt)
    note = (f"|B| = {field_nt:.0f} nT from {model_note} at the first 3D fix "
            f"({lat:.5f}, {lon:.5f}, {alt:.0f} m)")
    mag = data.mag if until_s is None else data.mag[data.mag[:, 0] <= until_s]
    fit, refused, level_note = _hard_soft(data, mag, field)
    note += level_note
    if align == "none" or len(data.att) < 2:
        return BootCalibration(data.boot, fit, refused, note, until_s=until_s)
    mag = mag[(mag[:, 0] >= data.gps[0, 0]) & (mag[:, 0] <= data.gps[-1, 0])]   # where the GPS gives the field
    att = [np.interp(mag[:, 0], data.att[:, 0], data.att[:, k]) for k in (1, 2, 3)]
    level = np.degrees(np.maximum(np.abs(wrap_pi(att[0])), np.abs(wrap_pi(att[1])))) <= MAX_ALIGN_TILT_DEG
    mag, att = mag[level], [a[level] for a in att]
    t = mag[:, 0]
    samples = mag[:, 1:4] if fit is None else (mag[:, 1:4] - np.array(fit.offset_nt)) @ np.array(fit.soft_iron).T
    ned = model.elements(*interp_gps(data.gps, t), when.decimal_year)
    try:
        alignment = fit_alignment(samples, *att, np.column_stack([ned.x_nt, ned.y_nt, ned.z_nt]), axes=align)
        return BootCalibration(data.boot, fit, refused, note, alignment, "", until_s)
    except CalibrationRefused as err:
        return BootCalibration(data.boot, fit, refused, note, None, str(err), until_s)


def _hard_soft(data: LogData, mag: np.ndarray, field) -> tuple[CalibrationFit | None, str, str]:
    """The full fit, else the level fit: (fit, refusal, what the level fit adds to the |B| note)."""
    try:
        return fit_calibration(mag[:, 1:4], float(field.f_nt)), "", ""
    except CalibrationRefused as err:
        full = str(err)
    if len(data.att) < 2:
        return None, full, ""
    # turns about the vertical only (a boat, a car): the level fit with the attitude's roll and pitch
    t = mag[:, 0]
    down = down_in_body(np.interp(t, data.att[:, 0], data.att[:, 1]), np.interp(t, data.att[:, 0], data.att[:, 2]))
    try:
        fit = fit_level_calibration(mag[:, 1:4], down, float(field.h_nt), float(field.z_nt))
    except CalibrationRefused as err:
        return None, f"{full.splitlines()[0]}; {str(err).splitlines()[0]}", ""
    return fit, "", (f" (H {float(field.h_nt):.0f} nT, Z {float(field.z_nt):.0f} nT; "
                 f"the full fit was refused: {full.splitlines()[0].removeprefix('calibration refused: ')})")


def calibrate_prefix(data: LogData, model_spec: str | None = None, date: str | None = None,
                     align: str = "xy") -> BootCalibration:
    """The calibration fitted on the first part of the boot only (fcmpc-replay's default, so that
    the fix error is judged on samples the fit never saw): of the prefixes ending at each of
    :data:`CALIBRATION_SHARES` of the span from the first 3D fix to the last magnetometer sample,
    the shortest with the most fits accepted (hard/soft iron before alignment)."""
    if len(data.gps) == 0 or len(data.mag) == 0:
        return calibrate_boot(data, model_spec, date, None, align)   # raises or refuses with the reason
    t0, t1 = float(data.gps[0, 0]), float(data.mag[-1, 0])
    best: BootCalibration | None = None
    for share in CALIBRATION_SHARES:
        cal = calibrate_boot(data, model_spec, date, t0 + share * (t1 - t0), align)
        if best is None or cal.accepted > best.accepted:
            best = cal
        if best.accepted == (2 if align == "none" else 3):
            break
    assert best is not None
    return best


def fc_compass_values(path: str | os.PathLike[str], compass: int = 1) -> dict[str, float]:
    """The flight controller's COMPASS_OFS/DIA/ODI values of ``compass`` in a DataFlash or tlog
    file (the last value of each; empty for a ULog, a CSV or a log without them)."""
    if sniff_format(path) in (ULOG, CSV):
        return {}
    from pymavlink import mavutil

    suffix = "" if compass == 1 else str(compass)
    wanted = {f"COMPASS_{k}{suffix}_{a}" for k in ("OFS", "DIA", "ODI") for a in "XYZ"}
    values: dict[str, float] = {}
    conn = mavutil.mavlink_connection(str(path))
    try:
        while (msg := conn.recv_match(type=["PARM", "PARAM_VALUE"])) is not None:
            name, value = ((msg.Name, msg.Value) if msg.get_type() == "PARM" else (msg.param_id, msg.param_value))
            if name in wanted:
                values[name] = float(value)
    finally:
        conn.close()
    return values


def _parm_text(values: dict[str, float], header: list[str]) -> str:
    return "\n".join([f"# {line}" for line in header] +
                     [f"{name} {format_value(float(values[name]))}" for name in sorted(values)]) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="fcmpc-calibrate", description=(
        "Fit the magnetometer's hard and soft iron from a log (the model's |B| at its GPS position) and "
        "write the companion's MAG_* and ArduPilot's COMPASS_* parameters."))
    parser.add_argument("log", metavar="LOG", help="ArduPilot DataFlash .bin, MAVLink .tlog, PX4 .ulg or a .csv")
    parser.add_argument("--model", default=None, help="WMM2010..WMM2025 or a .COF path (default: by the log's date)")
    parser.add_argument("--date", default=None, metavar="YYYY-MM-DD", help="the date of a log that carries none")
    parser.add_argument("--mag-instance", type=int, default=0, help="magnetometer instance (default 0)")
    parser.add_argument("--boot", type=int, default=None,
                        help="boot to calibrate, 1-based (default: the one with the most magnetometer samples)")
    parser.add_argument("--out", default=None, help="output folder (default out/calibrate/<log stem>)")
    parser.add_argument("--align", choices=ALIGN_AXES, default="xy",
                        help="the magnetometer's alignment to the body against the model's field direction: xy "
                             "(default) roll and pitch from the inclination, xyz also the yaw (for a yaw independent "
                             "of this compass), none")
    args = parser.parse_args(argv)
    try:
        boots = [b for b in read_boots(args.log, args.mag_instance) if len(b.mag)]
        if not boots:
            raise ValueError(f"{args.log}: no magnetometer {args.mag_instance} samples")
        if args.boot is not None:
            if not 1 <= args.boot <= boots[-1].boots:
                raise ValueError(f"--boot {args.boot}: the log has {boots[-1].boots} boot(s)")
            chosen = [b for b in boots if b.boot == args.boot - 1]
            if not chosen:
                raise ValueError(f"--boot {args.boot}: no magnetometer samples in that boot")
            data = chosen[0]
        else:
            data = max(boots, key=lambda b: len(b.mag))
        result = calibrate_boot(data, args.model, args.date, align=args.align)
        current = fc_compass_values(args.log, args.mag_instance + 1)
    except (SensorError, ValueError, OSError) as err:
        print(f"fcmpc-calibrate: {err}", file=sys.stderr)
        return 2
    print(f"{args.log}: boot {data.boot + 1} of {data.boots}, magnetometer {args.mag_instance}, "
          f"{len(data.mag)} samples")
    print(result.field_note)
    if result.fit is None:   # the reason on one line; the refused fit's figures, if any, on stdout
        reason, *figures = result.refused.splitlines()
        if figures:
            print("\n".join(figures))
        print(f"fcmpc-calibrate: {reason}", file=sys.stderr)
        return 2
    fit = result.fit
    print(result.describe())
    out = Path(args.out) if args.out else Path("out") / "calibrate" / Path(args.log).stem
    source = f"fcmpc-calibrate {Path(args.log).name} (boot {data.boot + 1}): {result.field_note}"
    quality = (f"residual {fit.residual_nt:.0f} nT rms over {fit.samples} samples, "
               f"{100 * fit.cell_share:.0f} % of the sphere's cells")
    values = companion_params(fit)
    if result.alignment is not None:
        values.update(alignment_params(result.alignment))
        quality += (f"; alignment residual {result.alignment.before_deg:.2f} -> {result.alignment.residual_deg:.2f} "
                    "deg rms")
    companion_path = out / "companion-mag.parm"
    try:   # a fit beyond the registry's ranges (MAG_SCALE_* 0.2-5, MAG_OFS_* +-3000 mG) is not written
        write_parm_file(companion_path, values, header=f"{source}\n{quality}\n"
                        "the companion's magnetometer calibration: corrected = R(MAG_ROT_*) soft iron (raw - MAG_OFS)")
    except ValueError as err:
        print(f"fcmpc-calibrate: the fit is outside the companion's parameter ranges: {err}", file=sys.stderr)
        return 2
    ap, angle = ardupilot_compass_params(fit, args.mag_instance + 1, current)
    composed = (f"composed with the log's {len(current)} COMPASS_* values in force" if current else
                "the logged field taken as raw (the log holds no COMPASS_* values)")
    ap_path = out / "ardupilot-compass.parm"
    out.mkdir(parents=True, exist_ok=True)
    ap_path.write_text(_parm_text(ap, [source, quality, composed + (
        f"; the symmetric matrix leaves out a {angle:.2f} deg rotation" if current else ""),
        "ArduPilot: corrected = [[DIA_X, ODI_X, ODI_Y], [ODI_X, DIA_Y, ODI_Z], [ODI_Y, ODI_Z, DIA_Z]] "
        "(raw + OFS), mGauss"]))
    print(f"ArduPilot's equivalents: {composed}" + (f" (a {angle:.2f} deg rotation left out)" if current else ""))
    print(f"written: {companion_path}, {ap_path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
