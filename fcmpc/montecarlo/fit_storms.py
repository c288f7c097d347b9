"""Fit on some storms, judge on others: the navigator's storm-time parameters from named storms.

    fcmpc-fit-storms --train halloween2003,stpatrick2015,march2011     # -> params/storms-<names>.parm
    fcmpc-fit-storms --loo may2024                                     # the same: every storm but may2024
    fcmpc-montecarlo --scenario may2024_real --storm-params loo         # scored on a storm it was not fitted on
    fcmpc-montecarlo --scenario may2024_real --params params/storms-halloween2003+march2011+stpatrick2015.parm

Each training storm is flown as its realistic scenario (``<name>_real``: the storm library's route and
main phase, in real time; :mod:`sitl.storms.events`) and its disturbance measured along the route by
the existing fits (:func:`sitl.world.build.storm_component_walks`,
:func:`sitl.world.build.storm_component_correlations`): the walks ``FUS_BQA_N/E/Z``, ``FUS_BQA_TN/TE/TZ``,
their correlations ``FUS_BQA_RNE/RNZ/REZ``, and with the ring current predicted from the storm's ring
index (SYM-H, else RC) at the ratio ``FUS_SYMH_K`` removed, the north residual ``FUS_SYMH_N/TN`` and
its correlations ``FUS_SYMH_RNE/RNZ``. The storms are pooled (:func:`pool`): a rate is the root mean
square of the storms' rates (the mean of their variance rates), a correlation time the median with a
random walk counted as infinitely long (so a component is a random walk unless most storms revert),
a correlation the mean.

With ``--by-miss`` (:mod:`fcmpc.montecarlo.fit_miss`) the fit goes on: the walks' rates are scaled
and ``FUS_SYMH_K`` chosen by what they do to the navigator's miss on the training storms (tuning
seeds 0-99 only), so the fit may choose not to trust the index; it writes
``params/storms-<names>-by-miss.parm``, which ``--storm-params loo`` then uses (:func:`storm_params_for`).

Not fitted, and why (docs/storms.md, "Fit on some storms, judge on others"): ``FUS_SYMH_K`` without
``--by-miss`` (the registry's 1.0 is the physics' cos(geomagnetic latitude) rounded, measured 1.02 on May 2024),
``FUS_KP_ON`` / ``FUS_SYMH_ON`` (NOAA's G1 and the Dst scale's moderate storm: definitions, not fits),
``FUS_BQA_DEG/NT`` (the innovations' adaptive walk, not measured on any storm).

The written file's header names the training storms (``# fitted on storms: a,b``, :func:`fitted_on`);
``fcmpc-montecarlo`` reads it and refuses to score a storm the parameters were fitted on
(:func:`check_held_out`), and records the training storms in its ``summary.json``.
"""
from __future__ import annotations

import functools
import math
import os
import re
import sys
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

from companion.cli import ArgumentParser, UsageError, run_main
from companion.params import SPEC_BY_NAME, write_parm_file
from sitl.scenario import Scenario, ScenarioError, load_scenario

__all__ = ["DEFAULTS_FITTED_ON", "FITTED_ON", "OwnStormError", "STORM_PARAMS", "check_held_out", "fit_storm",
           "fit_storms", "fitted_on", "leave_one_out", "main", "parm_header", "parm_name", "pool", "storm_params_for",
           "training_scenario"]

# What the fit writes: every storm-time walk of the registry (FUS_SYMH_K, FUS_KP_ON, FUS_SYMH_ON: see above).
STORM_PARAMS = ("FUS_BQA_N", "FUS_BQA_E", "FUS_BQA_Z", "FUS_BQA_TN", "FUS_BQA_TE", "FUS_BQA_TZ",
                "FUS_BQA_RNE", "FUS_BQA_RNZ", "FUS_BQA_REZ",
                "FUS_SYMH_N", "FUS_SYMH_TN", "FUS_SYMH_RNE", "FUS_SYMH_RNZ")
FITTED_ON = "fitted on storms:"   # the header line naming the training storms
BY_MISS = "fitted by miss:"   # the header line of a --by-miss file: what the fit chose
PARAMS_DIR = Path(__file__).resolve().parents[2] / "params"   # the committed fits (--storm-params loo reads them)
DEFAULTS_FITTED_ON = ("may2024",)   # the registry's storm-time defaults (companion/registry.py's descriptions)
_DIGITS = {"FUS_BQA_N": 1, "FUS_BQA_E": 1, "FUS_BQA_Z": 1, "FUS_SYMH_N": 1}   # nT/rt(h) to 0.1; others to 0.01


class OwnStormError(UsageError):
    """A storm scenario would be scored with parameters fitted on its own storm."""


def training_scenario(name: str) -> Scenario:
    """The storm library's event ``name`` flown as its realistic scenario, ``<name>_real``."""
    try:
        scenario = load_scenario(f"{name}_real")
    except ScenarioError as err:
        raise UsageError(f"storm {name!r}: no realistic scenario {name}_real to fit it on ({err})") from None
    if not scenario.storm.enabled or scenario.storm.event != name:
        raise UsageError(f"storm {name!r}: scenario {name}_real does not fly that storm")
    return scenario


def fit_storm(name: str, data_dir: str | os.PathLike[str] | None = None,
              symh_ratio: float | None = None) -> dict[str, float]:
    """One storm's storm-time parameters (unrounded) along its scenario's route in real time;
    ``symh_ratio`` is the ring-current ratio removed for the ``FUS_SYMH_*`` (default ``FUS_SYMH_K``'s)."""
    from sitl.world.build import storm_component_correlations, storm_component_walks
    ratio = float(SPEC_BY_NAME["FUS_SYMH_K"].default) if symh_ratio is None else float(symh_ratio)
    scenario = training_scenario(name)
    q, tau = storm_component_walks(scenario, data_dir)
    q_res, tau_res = storm_component_walks(scenario, data_dir, symh_ratio=ratio)
    rho = storm_component_correlations(scenario, data_dir)
    rho_res = storm_component_correlations(scenario, data_dir, symh_ratio=ratio)
    values = {f"FUS_BQA_{c}": q[i] for i, c in enumerate("NEZ")}
    values |= {f"FUS_BQA_T{c}": tau[i] for i, c in enumerate("NEZ")}
    values |= {f"FUS_BQA_R{p}": rho[i] for i, p in enumerate(("NE", "NZ", "EZ"))}
    values |= {"FUS_SYMH_N": q_res[0], "FUS_SYMH_TN": tau_res[0], "FUS_SYMH_RNE": rho_res[0],
               "FUS_SYMH_RNZ": rho_res[1]}
    return values


def pool(fits: Sequence[Mapping[str, float]]) -> dict[str, float]:
    """The storms' fits as one set, rounded as a ``.parm`` carries them: rates as the root mean square
    (variance rates averaged), correlation times as the median with 0 (a random walk) counted as
    infinite (infinite median: 0), correlations as the mean.

    >>> pool([{"FUS_BQA_N": 30.0, "FUS_BQA_TE": 0.0, "FUS_BQA_RNE": 0.2},
    ...       {"FUS_BQA_N": 40.0, "FUS_BQA_TE": 2.0, "FUS_BQA_RNE": 0.4}])
    {'FUS_BQA_N': 35.4, 'FUS_BQA_TE': 0.0, 'FUS_BQA_RNE': 0.3}
    """
    if not fits:
        raise ValueError("no storm to fit on")
    pooled: dict[str, float] = {}
    for name in fits[0]:
        values = np.array([fit[name] for fit in fits], dtype=float)
        if re.fullmatch(r"FUS_(BQA|SYMH)_T[NEZ]", name):
            median = float(np.median(np.where(values > 0.0, values, np.inf)))
            value = median if math.isfinite(median) else 0.0
        elif re.fullmatch(r"FUS_(BQA|SYMH)_R(NE|NZ|EZ)", name):
            value = float(np.mean(values))
        else:
            value = float(np.sqrt(np.mean(values ** 2)))
        pooled[name] = round(value, _DIGITS.get(name, 2)) + 0.0   # no -0.0
    return pooled


def fit_storms(names: Iterable[str], data_dir: str | os.PathLike[str] | None = None,
               symh_ratio: float | None = None) -> dict[str, float]:
    """The storm-time parameters (:data:`STORM_PARAMS`) fitted on the named storms, pooled (the north
    residual with the ring current at ``symh_ratio`` removed; default ``FUS_SYMH_K``'s); each storm's
    fit is computed once per process."""
    names = _names(names)
    return pool([_fit_once(name, None if data_dir is None else str(data_dir), symh_ratio) for name in names])


@functools.lru_cache(maxsize=64)
def _fit_once(name: str, data_dir: str | None, symh_ratio: float | None) -> dict[str, float]:
    return fit_storm(name, data_dir, symh_ratio)


def leave_one_out(held_out: str) -> tuple[str, ...]:
    """Every storm of the library but ``held_out`` (the training set to score it with)."""
    from sitl.storms.events import storm_events
    names = tuple(event.name for event in storm_events())
    if held_out not in names:
        raise UsageError(f"storm {held_out!r} is not in the storm library ({', '.join(names)})")
    return _names(n for n in names if n != held_out)


def parm_header(names: Sequence[str]) -> str:
    """The ``.parm`` header: the training storms on a line :func:`fitted_on` reads back."""
    return (f"{FITTED_ON} {','.join(names)}\n"
            "written by fcmpc-fit-storms (fcmpc/montecarlo/fit_storms.py): storm-time walks of each storm's realistic\n"
            "scenario (<name>_real, real time), pooled; FUS_SYMH_K, FUS_KP_ON, FUS_SYMH_ON are not fitted (registry's)")


def parm_name(names: Sequence[str], by_miss: bool = False) -> str:
    """The file name ``fcmpc-fit-storms`` writes for these training storms (under ``params/``)."""
    return f"storms-{'+'.join(_names(names))}{'-by-miss' if by_miss else ''}.parm"


def fitted_on(path: str | os.PathLike[str]) -> tuple[str, ...] | None:
    """The training storms a ``.parm`` file's header names, or None when it names none."""
    for raw in Path(path).read_text(encoding="utf-8", errors="replace").splitlines():
        line = raw.lstrip("#").strip()
        if raw.startswith("#") and line.startswith(FITTED_ON):
            return tuple(n.strip() for n in line[len(FITTED_ON):].split(",") if n.strip())
    return None


def check_held_out(scenario: Scenario, storms: Iterable[str] | None) -> None:
    """Raise :class:`OwnStormError` when ``scenario`` flies a storm among ``storms``, the storms its
    parameters were fitted on."""
    if storms is None or not scenario.storm.enabled:
        return
    if scenario.storm.event in set(storms):
        raise OwnStormError(f"scenario {scenario.name!r} flies the storm {scenario.storm.event!r}, and its storm "
                            f"parameters were fitted on {','.join(storms)}: score it with parameters fitted on "
                            f"other storms (--storm-params loo)")


def storm_params_for(scenario: Scenario, spec: str,
                     data_dir: str | os.PathLike[str] | None = None) -> tuple[dict[str, float], tuple[str, ...]]:
    """``fcmpc-montecarlo --storm-params``: ``loo`` (every other storm of the library) or a comma list of
    storms; the fitted values and their training storms, refused (:func:`check_held_out`) when they
    include the scenario's own."""
    if not scenario.storm.enabled:
        raise UsageError(f"--storm-params: scenario {scenario.name!r} has no storm")
    loo = spec.strip().lower() == "loo"
    names = leave_one_out(scenario.storm.event) if loo else _names(spec.split(","))
    check_held_out(scenario, names)
    committed = PARAMS_DIR / parm_name(names, by_miss=True)
    if loo and committed.is_file() and fitted_on(committed) == names:   # the fit by miss, when made
        from companion.params import read_parm_file

        return read_parm_file(committed), names
    return fit_storms(names, data_dir), names


def _names(names: Iterable[str]) -> tuple[str, ...]:
    """Storm names, stripped, unique, sorted (the training set does not depend on their order)."""
    cleaned = tuple(sorted({n.strip() for n in names if n.strip()}))
    if not cleaned:
        raise UsageError("name at least one training storm")
    return cleaned


def _run(argv: list[str] | None) -> int:
    parser = ArgumentParser(prog="fcmpc-fit-storms", description=__doc__.split("\n")[0])
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--train", metavar="NAMES", help="comma list of the storm library's storms to fit on")
    group.add_argument("--loo", metavar="NAME", help="fit on every storm of the library but this one "
                                                     "(--by-miss: 'all', one fit per held-out storm)")
    parser.add_argument("--out", default=None, help="the .parm to write; default params/storms-<names>.parm")
    parser.add_argument("--data-dir", default=None, help="real data folder; default ../shared/data")
    parser.add_argument("--by-miss", action="store_true",
                        help="scale the walks and choose FUS_SYMH_K by the navigator's miss on the training storms "
                             "(fcmpc.montecarlo.fit_miss); writes params/storms-<names>-by-miss.parm")
    parser.add_argument("--seeds", type=int, default=4, help="--by-miss: tuning seeds 0..N-1 (N <= 100); default 4")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="--by-miss: worker processes")
    parser.add_argument("--scales", default=None, help="--by-miss: comma list of the walks' scales; default 0.1,0.3,1")
    parser.add_argument("--ratios", default=None, help="--by-miss: comma list of FUS_SYMH_K; default 0,0.5,1")
    parser.add_argument("--store", default="out/fit-by-miss", help="--by-miss: where the runs are kept (a second "
                                                                   "call flies only what is missing)")
    args = parser.parse_args(argv)
    if args.by_miss:
        return _run_by_miss(args)
    names = leave_one_out(args.loo) if args.loo else _names(args.train.split(","))
    fits = {name: fit_storm(name, args.data_dir) for name in names}
    pooled = pool(list(fits.values()))
    width = max(len(n) for n in (*names, "pooled"))
    print(f"{'storm':<{width}} " + " ".join(f"{p[4:]:>9}" for p in STORM_PARAMS))
    for name, fit in {**fits, "pooled": pooled}.items():
        print(f"{name:<{width}} " + " ".join(f"{fit[p]:9.2f}" for p in STORM_PARAMS))
    out = Path(args.out) if args.out else Path("params") / parm_name(names)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_parm_file(out, pooled, parm_header(names))
    print(f"written: {out} ({FITTED_ON} {','.join(names)})")
    return 0


def _run_by_miss(args) -> int:
    """``--by-miss``: each training set (``--train``, ``--loo NAME``, or ``--loo all``) fitted by the miss."""
    from fcmpc.montecarlo.engines import Engine
    from fcmpc.montecarlo.fit_miss import fit_by_miss, format_fit
    from fcmpc.montecarlo.store import RunStore
    from sitl.storms.events import storm_events

    if args.loo and args.loo.strip().lower() == "all":
        sets = [leave_one_out(event.name) for event in storm_events()]
    else:
        sets = [leave_one_out(args.loo) if args.loo else _names(args.train.split(","))]
    if args.out and len(sets) > 1:
        raise UsageError("--out with --loo all: one file per held-out storm, named for its training storms")
    try:
        grid = {k: tuple(float(v) for v in getattr(args, k).split(",")) for k in ("scales", "ratios") if getattr(args, k)}
        fits = fit_by_miss(sets, lambda names, ratio: fit_storms(names, args.data_dir, ratio), range(args.seeds),
                           Engine("local", args.workers), args.data_dir,
                           store=RunStore(Path(args.store) / "runs"), **grid)
    except ValueError as err:
        raise UsageError(f"--seeds: {err}") from None
    for fit in fits:
        print(format_fit(fit))
        chosen = fit.chosen
        score = next(score for cand, score, _ in fit.scores if cand == chosen)
        out = Path(args.out) if args.out else PARAMS_DIR / parm_name(fit.storms, by_miss=True)
        out.parent.mkdir(parents=True, exist_ok=True)
        header = (f"{parm_header(fit.storms).splitlines()[0]}\n{BY_MISS} walks x {chosen.scale:g}, FUS_SYMH_K "
                  f"{chosen.ratio:g}; score {score:.3f} (mean miss over the feed-off mean miss, 1: the index pays "
                  f"nothing) on seeds {fit.seeds[0]}-{fit.seeds[-1]}\nwritten by fcmpc-fit-storms --by-miss "
                  "(fcmpc/montecarlo/fit_miss.py): the truth-fitted walks of each training storm pooled, then "
                  "scaled and the ring-current ratio chosen by the navigator's miss on the training storms")
        write_parm_file(out, dict(chosen.values), header)
        print(f"written: {out} ({FITTED_ON} {','.join(fit.storms)})\n")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_main("fcmpc-fit-storms", lambda: _run(argv), (ScenarioError,))


if __name__ == "__main__":
    sys.exit(main())
