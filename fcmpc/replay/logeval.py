"""A whole log evaluated: its boots, the flights of each boot, one evaluation per flight.

A boot without a flight (never armed, or armed without leaving the ground) is evaluated once
as a recording, so its D and I are still compared with the model, and is labelled so; a boot
without GPS fixes, magnetometer or attitude cannot be judged and is listed with the reason.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field, replace

import numpy as np

from companion.nav.magnetometer import MagCalibration

from fcmpc.replay.calibrate import CALIBRATION_SHARES, calibrate_boot, calibrate_prefix
from fcmpc.replay.evaluate import DEFAULT_WINDOWS_S, evaluate_flight
from fcmpc.replay.logdata import LogData
from fcmpc.replay.reading import read_boots
from fcmpc.replay.models import log_date, select_model
from fcmpc.replay.records import ReplayEvaluation
from fcmpc.replay.segments import find_flights

__all__ = ["CALIBRATION_FITS", "LogEvaluation", "apply_calibration", "evaluate_boots", "evaluate_log", "evaluate"]

# fcmpc-replay's calibration: "first-part" fits on the boot's first part and judges the rest
# (calibrate_prefix's rule); "all-samples" fits on every sample and judges the same samples
CALIBRATION_FITS = ("first-part", "all-samples")


@dataclass
class LogEvaluation:
    """Every flight (or recording) evaluated, in log order, and what could not be."""

    path: str
    boots: int
    evaluations: list[ReplayEvaluation] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)

    @property
    def labels(self) -> list[str]:
        return [unit_label(ev) for ev in self.evaluations]


def unit_label(ev: ReplayEvaluation) -> str:
    """``boot2-flight1`` style name of one evaluation (folder name of its outputs)."""
    kind = f"flight{ev.flight}" if ev.is_flight else "recording"
    return f"boot{ev.boot + 1}-{kind}"


def evaluate_log(
    path: str | os.PathLike[str],
    model_spec: str | None = None,
    windows_s: tuple[float, ...] = DEFAULT_WINDOWS_S,
    prior_offset_km: float = 10.0,
    crash_guard_s: float = 10.0,
    mag_instance: int = 0,
    date: str | None = None,
    calibrate: bool = False,
    calibration_fit: str = "first-part",
    align: str = "xy",
) -> LogEvaluation:
    """Split the log into boots and flights and evaluate each; SensorError/ValueError on bad input.

    ``calibrate``: fit the magnetometer's hard and soft iron against the model's |B| at its first
    fix and its alignment against the model's direction (``align``, :mod:`fcmpc.replay.calibrate`),
    evaluate with them applied, and keep each window's fix error before them (``fcmpc-replay``
    does, unless ``--no-calibration``). ``calibration_fit`` (one of :data:`CALIBRATION_FITS`):
    fitted on the boot's first part and judged, before and after, on the rest only (the default),
    or fitted on every sample and judged on the same."""
    return evaluate_boots(read_boots(path, mag_instance), model_spec, windows_s, prior_offset_km, crash_guard_s,
                          date, calibrate, calibration_fit, align)


def evaluate_boots(
    boots: list[LogData],
    model_spec: str | None = None,
    windows_s: tuple[float, ...] = DEFAULT_WINDOWS_S,
    prior_offset_km: float = 10.0,
    crash_guard_s: float = 10.0,
    date: str | None = None,
    calibrate: bool = False,
    calibration_fit: str = "first-part",
    align: str = "xy",
) -> LogEvaluation:
    """:func:`evaluate_log` of boots already read (or changed: a known distortion applied)."""
    if calibration_fit not in CALIBRATION_FITS:
        raise ValueError(f"calibration_fit must be one of {', '.join(CALIBRATION_FITS)}, got {calibration_fit!r}")
    path = boots[0].path if boots else ""
    result = LogEvaluation(str(path), len(boots))
    errors: list[str] = []
    for data in boots:
        name = f"boot {data.boot + 1} of {data.boots}"
        if len(data.gps) < 2 or len(data.mag) < 2 or len(data.att) < 2:
            result.skipped.append(f"{name}: not evaluated ({len(data.gps)} 3D GPS fixes, {len(data.mag)} "
                                  f"magnetometer {data.mag_instance} and {len(data.att)} attitude samples; "
                                  "needs at least two of each)")
            continue
        when = log_date(data, date)
        try:
            model, model_note = select_model(model_spec, when)
        except ValueError as err:
            errors.append(f"{name}: {err}" if data.boots > 1 else str(err))
            continue
        flights, notes = find_flights(data)
        result.skipped += [f"{name}: {n}" for n in notes]
        correction, cal_note, judged_from = None, "", None
        if calibrate:
            cal = (calibrate_prefix(data, model_spec, date, align) if calibration_fit == "first-part"
                   else calibrate_boot(data, model_spec, date, None, align))
            correction = cal.calibration
            judged_from = cal.until_s if correction is not None else None
            span = ("every sample of the boot, judged on the same samples" if cal.until_s is None else
                    f"the boot's samples up to {cal.until_s:.1f} s (from its first fix: the shortest of "
                    f"{', '.join(f'{s:.2f}' for s in CALIBRATION_SHARES)} of the boot with the most fits accepted); "
                    f"judged from {cal.until_s:.1f} s only, before and after")
            cal_note = (f"fitted on {span}; {cal.field_note}:\n{cal.describe()}" if correction is not None
                        else f"not applied ({cal.field_note}): {cal.refused.splitlines()[0]}; "
                             f"{cal.alignment_refused.splitlines()[0] if cal.alignment_refused else ''}")
        units = [(None, data)] if not flights else [(f, data.window(*f.window_s)) for f in flights]
        for k, (flight, part) in enumerate(units):
            try:
                ev = evaluate_flight(part, flight, model, model_note, when, windows_s, prior_offset_km, crash_guard_s,
                                     judged_from)
                if correction is not None:
                    before = ev.fix_rows
                    ev = evaluate_flight(apply_calibration(part, correction), flight, model, model_note, when,
                                         windows_s, prior_offset_km, crash_guard_s, judged_from)
                    ev.fix_rows_before = before
            except ValueError as err:  # a flight without magnetometer or attitude samples in its window
                result.skipped.append(f"{name}, flight {k + 1}: not evaluated: {err}")
                continue
            ev.calibration = cal_note
            ev.flight = k + 1 if flight is not None else 0
            ev.flights = len(flights)
            result.evaluations.append(ev)
    if not result.evaluations:
        reasons = errors + result.skipped
        raise ValueError("; ".join(reasons) if reasons else f"{path}: nothing to evaluate")
    result.skipped += errors
    return result


def apply_calibration(data: LogData, calibration: MagCalibration) -> LogData:
    """The same data with ``calibration`` applied to its magnetometer samples."""
    mag = data.mag.copy()
    if len(mag):
        mag[:, 1:4] = (mag[:, 1:4] - np.array(calibration.offset_nt)) @ np.array(calibration.soft_iron).T
    return replace(data, mag=mag)


def evaluate(
    path: str | os.PathLike[str],
    model_spec: str | None = None,
    windows_s: tuple[float, ...] = DEFAULT_WINDOWS_S,
    prior_offset_km: float = 10.0,
    crash_guard_s: float = 10.0,
    mag_instance: int = 0,
    date: str | None = None,
) -> ReplayEvaluation:
    """The evaluation of a log holding one flight (or one recording); ValueError naming the
    flights when it holds several (use :func:`evaluate_log`)."""
    result = evaluate_log(path, model_spec, windows_s, prior_offset_km, crash_guard_s, mag_instance, date)
    if len(result.evaluations) > 1:
        raise ValueError(f"{path} holds {len(result.evaluations)} flights or recordings "
                         f"({', '.join(result.labels)}): evaluate them with evaluate_log")
    return result.evaluations[0]


