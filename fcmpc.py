"""``module load fcmpc`` in MAVProxy: MAVProxy imports ``MAVProxy.modules.mavproxy_fcmpc`` or, failing
that, the top-level module named as typed, this one. The module itself is :mod:`fcmpc_mavproxy`."""
from fcmpc_mavproxy.module import init

__all__ = ["init"]
