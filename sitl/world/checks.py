"""Checks of the world's configuration values: a value no world has (a negative 1-sigma, a zero
rate or time, a vehicle that cannot move) is one ValueError naming the key and the value, which a
scenario file (:func:`sitl.scenario.load_scenario`) and a sweep (``fcmpc-montecarlo --sweep``)
turn into one clear line.

>>> from dataclasses import dataclass
>>> @dataclass(frozen=True)
... class Noise:
...     sigma_nt: float = -1.0
>>> require(Noise(), ("sigma_nt",), lambda v: v >= 0.0, "finite and not negative")
Traceback (most recent call last):
ValueError: sigma_nt = -1.0: must be finite and not negative
"""
from __future__ import annotations

import math
from typing import Callable, Iterable

__all__ = ["require"]


def require(config: object, names: Iterable[str], ok: Callable[[float], bool], what: str) -> None:
    """ValueError unless each named field of ``config`` (each element, for a tuple) is a finite
    number for which ``ok`` holds; ``what`` says what it must be."""
    for name in names:
        value = getattr(config, name)
        for v in value if isinstance(value, tuple) else (value,):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and ok(v)):
                raise ValueError(f"{name} = {value!r}: must be {what}")
