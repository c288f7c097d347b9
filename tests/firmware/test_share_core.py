"""The JSON rig's lockstep pair on one CPU (:func:`fcmpc.firmware.ardupilot_json_rig.share_core`): real processes,
their main threads on the instance's CPU, their other threads (ArduPilot's logger) on the rest."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from fcmpc.firmware.ardupilot_json_rig import share_core
from fcmpc.firmware.processes import stop_process

# a main thread and a second thread that lives until stdin closes (as ArduPilot's logger lives with it)
_TWO_THREADS = ("import sys, threading; threading.Thread(target=sys.stdin.read, daemon=True).start(); "
                "print(threading.get_native_id(), flush=True); sys.stdin.read()")


def _process_with_a_thread() -> tuple[subprocess.Popen, int]:
    proc = subprocess.Popen([sys.executable, "-c", _TWO_THREADS], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            text=True)
    proc.stdout.readline()                                     # the second thread has started
    others = [int(t) for t in os.listdir(f"/proc/{proc.pid}/task") if int(t) != proc.pid]
    return proc, others[0]


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity") or len(os.sched_getaffinity(0)) < 2,
                    reason="needs two CPUs and Linux affinity")
def test_the_pairs_main_threads_share_the_instances_cpu_and_their_other_threads_keep_off_it():
    cpus = sorted(os.sched_getaffinity(0))
    procs = [_process_with_a_thread() for _ in range(2)]
    try:
        for instance in (0, 1):
            core = share_core(tuple(p.pid for p, _ in procs), instance)
            assert core == cpus[instance % len(cpus)]
            for proc, thread in procs:
                assert os.sched_getaffinity(proc.pid) == {core}
                assert os.sched_getaffinity(thread) == set(cpus) - {core}
    finally:
        for proc, _ in procs:
            proc.stdin.close()
            stop_process(proc, 5.0)


def test_a_gone_process_is_no_error():
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    share_core((proc.pid,), 3)          # nothing to pin: no exception


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity") or len(os.sched_getaffinity(0)) < 2,
                    reason="needs two CPUs and Linux affinity")
def test_a_machine_at_the_load_limit_is_left_to_the_scheduler():
    proc, thread = _process_with_a_thread()
    try:
        before = os.sched_getaffinity(proc.pid)
        assert share_core((proc.pid,), 0, below_load_per_cpu=0.0) is None     # any load average is >= 0
        assert os.sched_getaffinity(proc.pid) == before and os.sched_getaffinity(thread) == before
    finally:
        proc.stdin.close()
        stop_process(proc, 5.0)
