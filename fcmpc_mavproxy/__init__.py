"""The Fc-MPC companion in MAVProxy (issue 50): ``module load fcmpc``.

:mod:`~fcmpc_mavproxy.module` is the MAVProxy module (console commands, map overlay);
:mod:`~fcmpc_mavproxy.ellipse` the confidence ellipse's geometry (pure). What the companion's
messages mean is :mod:`companion.operator_status`'s, read there by
:class:`~companion.operator_status.StatusReader`. MAVProxy imports the top-level module
``fcmpc`` (``fcmpc.py``), which only re-exports :func:`fcmpc_mavproxy.module.init`.
The user guide is docs/mavproxy.md.
"""
