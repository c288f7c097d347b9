"""``fcmpc-soak``: throw hostile MAVLink at a running companion and print the issue-10 table.

    fcmpc-soak --frames 100000                 # simulator + companion on loopback, ~2000 datagrams/s
    fcmpc-soak --frames 20000 --signing        # with a signing key: unsigned GCS writes too

Exit 0 when every harm count is zero (crashes, bad setpoints, stalls, parameters changed by
strangers, reboots believed, mission restarts), 1 otherwise. The library is :mod:`fcmpc.soak`.
"""
from __future__ import annotations

import sys
from datetime import datetime
from pathlib import Path

from companion.cli import ArgumentParser, UsageError, run_main

__all__ = ["main"]


def _run(argv: list[str] | None) -> int:
    p = ArgumentParser(prog="fcmpc-soak", description="Soak the companion with hostile MAVLink; print the table.")
    p.add_argument("--frames", type=int, default=100_000, help="hostile datagrams to send (default 100000)")
    p.add_argument("--rate-hz", type=float, default=2000.0, help="datagrams per wall second (default 2000)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--signing", action="store_true", help="run the companion with a new signing key")
    p.add_argument("--out", default=None, help="work folder; default out/soak/<time>")
    args = p.parse_args(argv)
    if args.frames < 1 or not args.rate_hz > 0:
        raise UsageError("--frames must be >= 1 and --rate-hz > 0")
    from fcmpc.soak.run import format_table, soak

    workdir = Path(args.out) if args.out else Path("out") / "soak" / f"{datetime.now():%Y%m%d-%H%M%S}"
    key = None
    if args.signing:
        from companion.io.link.signing import passphrase_key, write_key_file

        key = write_key_file(workdir / "signing.key", passphrase_key(f"soak-{args.seed}"), overwrite=True)

    def progress(k: int) -> None:
        if k % 20000 == 0:
            print(f"fcmpc-soak: {k} frames sent", file=sys.stderr, flush=True)

    result = soak(args.frames, workdir, seed=args.seed, rate_hz=args.rate_hz, signing_key=key, progress=progress)
    print(format_table(result))
    print(f"({result.wall_s:.0f} s of wall time; records in {workdir})")
    return 0 if result.all_zero else 1


def main(argv: list[str] | None = None) -> int:
    return run_main("fcmpc-soak", lambda: _run(argv))


if __name__ == "__main__":
    sys.exit(main())
