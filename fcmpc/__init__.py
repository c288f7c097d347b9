"""fcmpc's tools: everything that runs beside the vehicle's code (:mod:`companion`) and the
simulated world (:mod:`sitl`), one package per tool, each with its command line in ``cli``:

    fly         fcmpc-fly: one closed-loop mission, simulator (or firmware) and companion as processes
    montecarlo  fcmpc-montecarlo, fcmpc-fit-storms, fcmpc-results: runs, engines, sweeps, storm fits, tables
    bench       fcmpc-bench: each part timed beside its anchors
    soak        fcmpc-soak: hostile MAVLink against a running companion
    replay      fcmpc-replay, fcmpc-calibrate: a recorded flight log evaluated against its own GPS
    mavproxy    ``module load fcmpc`` in MAVProxy: console commands and the map overlay
    paramdoc    fcmpc-params: the parameter reference generated from companion/registry.py

Arrows: the tools import :mod:`companion` and :mod:`sitl`; neither imports them
(tests/test_architecture.py). ``scripts/X.py`` are thin files over the same ``main`` functions.

This package is also MAVProxy's module ``fcmpc``: ``module load fcmpc`` imports
``MAVProxy.modules.mavproxy_fcmpc`` or, failing that, the top-level name as typed, this package,
and calls its :func:`init`. MAVProxy is imported only then, so the other tools never need it.
"""
from __future__ import annotations

__all__ = ["init"]


def init(mpstate):
    """MAVProxy's module entry: the :class:`fcmpc.mavproxy.module.FcmpcModule` for ``mpstate``."""
    from fcmpc.mavproxy.module import init as module_init

    return module_init(mpstate)
