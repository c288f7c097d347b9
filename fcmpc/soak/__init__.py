"""Soak the running companion with hostile MAVLink over loopback and judge what it did (issue 10).

:mod:`~fcmpc.soak.hostile` makes the datagrams (one generator per class, seeded);
:mod:`~fcmpc.soak.run` starts the simulator and the companion as real processes, sends the
datagrams from many source ports while the mission runs, and judges the records
(:class:`~fcmpc.soak.run.SoakResult`, :func:`~fcmpc.soak.run.format_table`). ``fcmpc-soak``
(``scripts/soak.py``) is the command line; ``tests/reliability`` runs short soaks.
"""
