"""``fcmpc-signing-key``: make the companion's MAVLink signing key and say how to share it.

    fcmpc-signing-key /etc/fcmpc/signing.key

writes a new 32-byte key (permission 0600; refuses to overwrite without ``--force``) derived,
as MAVProxy does, from a random passphrase, and prints what to paste where:

* MAVProxy, connected to the flight controller: ``signing setup PASSPHRASE`` sends SETUP_SIGNING
  (the key and a start timestamp) to the autopilot, which stores it, and signs MAVProxy's own
  link; later sessions need only ``signing key PASSPHRASE``;
* any other tool: SETUP_SIGNING with ``secret_key`` the 32 bytes printed in hex and
  ``initial_timestamp`` the value printed (10 us units since 2015-01-01);
* the companion: ``fcmpc-companion --signing-key FILE``.

The passphrase and the hex key are printed once, to the terminal of the person who asked; they
are never logged or sent by the companion.
"""
from __future__ import annotations

import secrets
import sys
import time

from companion.cli import ArgumentParser, run_main
from companion.io.link.signing import passphrase_key, signing_timestamp, write_key_file

__all__ = ["instructions", "main"]


def instructions(path: str, passphrase: str, key: bytes, timestamp: int) -> str:
    """The text printed after a key is made (what to paste into MAVProxy, SETUP_SIGNING, the companion)."""
    return "\n".join([
        f"signing key written to {path} (permission 0600: keep it so; copy it to the companion board only)",
        "",
        "MAVProxy, connected to the flight controller (programs the autopilot and signs MAVProxy's link):",
        f"    signing setup {passphrase}",
        f"  later sessions:  signing key {passphrase}",
        "",
        "Other ground stations / scripts: send SETUP_SIGNING to the autopilot with",
        f"    secret_key        = {key.hex()}",
        f"    initial_timestamp = {timestamp}",
        "",
        "Companion:",
        f"    fcmpc-companion --signing-key {path} ...",
        "",
    ])


def _run(argv: list[str] | None) -> int:
    parser = ArgumentParser(prog="fcmpc-signing-key",
                            description="Make a MAVLink 2 signing key for the companion and print how to share it.")
    parser.add_argument("path", metavar="KEY_FILE", help="where to write the key (created with permission 0600)")
    parser.add_argument("--force", action="store_true", help="replace an existing key file")
    args = parser.parse_args(argv)
    passphrase = secrets.token_urlsafe(24)     # 144 random bits, ASCII, no spaces (one MAVProxy argument)
    key = passphrase_key(passphrase)
    path = write_key_file(args.path, key, overwrite=args.force)
    sys.stdout.write(instructions(str(path), passphrase, key, signing_timestamp(time.time())))
    return 0


def main(argv: list[str] | None = None) -> int:
    from companion.io.link.signing import SigningError

    return run_main("fcmpc-signing-key", lambda: _run(argv), user_errors=(SigningError,))


if __name__ == "__main__":
    sys.exit(main())
