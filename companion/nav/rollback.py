"""Take back a step: the attributes of the navigator's stateful parts, saved before and restored after.

A control step changes its mission, its gradient, its filter and that filter's parts; when the step
ends in a measurement it must reject (a value that drove the filter off the Earth, a covariance
that is no longer one, a QP the measured gradient made infeasible), :class:`Checkpoint` puts each
part back as it was, so the rejected step has changed nothing and the next one dead-reckons over
the whole gap (:meth:`companion.nav.mission.Mission.step`).

One level deep: each part's attributes are kept, with its lists, dicts and arrays copied (the
step appends to lists, and the filter writes some arrays in place); the objects they hold are
shared, so every part whose own attributes a step changes is named to the checkpoint. What the
step replaces whole (a new estimate, a new last command) needs no copy, and neither do the
arrays of filterpy's KalmanFilter, which its predict and update assign anew, never write into
(26 of them, half the checkpoint's cost when copied).

>>> class Part: pass
>>> part = Part(); part.k, part.moves = 1, [1.0]
>>> saved = Checkpoint(part)
>>> part.k, part.new = 2, "added"; part.moves.append(2.0)
>>> saved.restore(); (part.k, part.moves, hasattr(part, "new"))
(1, [1.0], False)
"""
from __future__ import annotations

import numpy as np
from filterpy.kalman import KalmanFilter

__all__ = ["Checkpoint"]


def _copied(value):
    """A list, dict or array copied (their items shared), anything else as it is."""
    if isinstance(value, np.ndarray):
        return value.copy()
    if isinstance(value, list):
        return list(value)
    if isinstance(value, dict):
        return dict(value)
    return value


class Checkpoint:
    """The attributes of ``parts`` (None entries skipped) as they are now; :meth:`restore` puts them back."""

    def __init__(self, *parts) -> None:
        self._saved = [(part, dict(vars(part)) if isinstance(part, KalmanFilter)
                        else {name: _copied(value) for name, value in vars(part).items()})
                       for part in parts if part is not None]

    def restore(self) -> None:
        """Every saved part's attributes as they were (attributes added since are removed); once."""
        for part, attributes in self._saved:
            state = vars(part)
            state.clear()
            state.update(attributes)
