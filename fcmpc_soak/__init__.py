"""Soak the running companion with hostile MAVLink over loopback and judge what it did (issue 10).

:mod:`~fcmpc_soak.hostile` makes the datagrams (one generator per class, seeded);
:mod:`~fcmpc_soak.run` starts the simulator and the companion as real processes, sends the
datagrams from many source ports while the mission runs, and judges the records
(:class:`~fcmpc_soak.run.SoakResult`, :func:`~fcmpc_soak.run.format_table`). ``fcmpc-soak``
(``scripts/soak.py``) is the command line; ``tests/reliability`` runs short soaks.
"""
