"""Bounded stream fuzz of the running companion over loopback (real processes: the simulator, the
companion, and this process as the attacker; :mod:`fcmpc.soak`). Every harm count must be zero:
no crash, no non-finite or over-cruise setpoint, the mission still stepping, no parameter changed
by a stranger, no reboot believed, no mission restarted (issue 10)."""
from __future__ import annotations

import pytest

from companion.io.link.signing import passphrase_key, write_key_file
from fcmpc.soak.run import format_table, soak


def _check(result) -> None:
    table = format_table(result)
    assert result.setpoints > 0, table            # the mission really was steering during the attack
    assert result.all_zero, table


def test_short_soak_harms_nothing(tmp_path):
    result = soak(1500, tmp_path, seed=1, rate_hz=1500.0)
    _check(result)
    assert result.link["param_sets_from_strangers"] > 0, format_table(result)   # the attack reached the server


@pytest.mark.slow
def test_long_soak_with_signing_harms_nothing(tmp_path):
    key = write_key_file(tmp_path / "signing.key", passphrase_key("soak"))
    result = soak(30_000, tmp_path / "run", seed=2, rate_hz=2000.0, signing_key=key)
    _check(result)
    # signed: strangers' and the spoofed GCS's unsigned writes stop at the signature check
    assert sum(result.link["unsigned_refused"].values()) > 0, format_table(result)
