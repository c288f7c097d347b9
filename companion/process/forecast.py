"""The route's prediction said to the operator before the mission (issue 46, item 7).

While READY, the mission about to fly is predicted (:func:`companion.nav.prediction.predict_route`:
the elements for the flight controller's heading source, how far apart their gradients are along
the route, and the navigator's own 1-sigma and 95 % radius at arrival) and said in STATUSTEXT,
once per configuration. The prediction flies the navigator's step a hundred-odd times, a few
seconds of CPU: on a wall-paced link it runs on a thread of its own and is said when ready, so the
control loop never waits for it; in lockstep (``--lockstep``) the world waits for the companion
anyway, so it is computed in the tick, and a run says the same words at the same simulated time.

Which position source it assumes: an independent INS only when ``FUS_MODEL 2`` declares one; by
default dead reckoning between fixes, what ArduPilot and PX4 without a navigation-grade INS give.
"""
from __future__ import annotations

import threading
from typing import Callable

from companion.nav.prediction import RoutePrediction, predict_route
from companion.params import NavConfig

__all__ = ["RouteForecast"]

INS_MODEL = 2    # FUS_MODEL 2: the error-state filter on an independent INS


class RouteForecast:
    """Predicts a configuration once, off the control loop unless ``inline``, and says it once."""

    def __init__(self, say: Callable[[str], None], inline: bool) -> None:
        self._say = say
        self._inline = inline
        self._key: NavConfig | None = None
        self._done: tuple[NavConfig, RoutePrediction | None, str] | None = None   # written by the worker
        self._said_for: NavConfig | None = None
        self.said: RoutePrediction | None = None   # the prediction last said (summary.json's route_prediction)

    def request(self, config: NavConfig) -> None:
        """Predict ``config`` (elements already resolved against the heading source), unless it is
        the one last asked for."""
        if config == self._key:
            return
        self._key = config
        if self._inline:
            self._work(config)
        else:
            threading.Thread(target=self._work, args=(config,), name="fcmpc-forecast", daemon=True).start()
        self.poll()

    def poll(self) -> None:
        """Say the prediction of the configuration last asked for, once, when it is ready."""
        done = self._done
        if done is None or done[0] != self._key or self._said_for == self._key:
            return
        self._said_for = self._key
        prediction, error = done[1], done[2]
        self.said = prediction
        lines = prediction.lines() if prediction is not None else [f"no prediction: {error}"]
        for line in lines:
            self._say(f"FcMPC: route: {line}")

    def _work(self, config: NavConfig) -> None:
        try:
            result: tuple = (config, predict_route(config, compass_derived=False,
                                                   has_ins=config.fusion_model == INS_MODEL), "")
        except (ValueError, ArithmeticError) as err:   # a configuration the prediction cannot fly
            result = (config, None, f"{type(err).__name__}: {err}")
        self._done = result
