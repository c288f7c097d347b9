"""The Fc-MPC companion in MAVProxy (issue 50): ``module load fcmpc``.

:mod:`~fcmpc.mavproxy.module` is the MAVProxy module (console commands, map overlay);
:mod:`~fcmpc.mavproxy.ellipse` the confidence ellipse's geometry (pure). What the companion's
messages mean is :mod:`companion.operator_status`'s, read there by
:class:`~companion.operator_status.StatusReader`. MAVProxy imports the top-level package
:mod:`fcmpc`, whose ``init`` imports :func:`fcmpc.mavproxy.module.init` when it is called.
The user guide is docs/mavproxy.md.
"""
