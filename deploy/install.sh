#!/bin/sh
# Install the companion as a systemd service (run as root on the companion board, from the repository).
# Idempotent: re-running updates the program and the unit, never an existing key or parameter file.
set -eu
REPO=$(cd "$(dirname "$0")/.." && pwd)
id fcmpc >/dev/null 2>&1 || useradd --system --home-dir /var/lib/fcmpc --shell /usr/sbin/nologin fcmpc
install -d -o root -g root -m 0755 /opt/fcmpc
[ -x /opt/fcmpc/venv/bin/python ] || python3 -m venv /opt/fcmpc/venv
/opt/fcmpc/venv/bin/pip install --quiet "$REPO"
install -d -o fcmpc -g fcmpc -m 0700 /etc/fcmpc /var/lib/fcmpc /var/lib/fcmpc/logs
[ -f /etc/fcmpc/companion.env ] || install -o root -g root -m 0644 "$REPO/deploy/companion.env" /etc/fcmpc/companion.env
[ -f /etc/fcmpc/companion.parm ] || install -o fcmpc -g fcmpc -m 0600 "$REPO/params/defaults.parm" /etc/fcmpc/companion.parm
if [ ! -f /etc/fcmpc/signing.key ]; then
    # prints the MAVProxy line once: copy it now, it is not stored
    runuser -u fcmpc -- /opt/fcmpc/venv/bin/fcmpc-signing-key /etc/fcmpc/signing.key
fi
chown fcmpc:fcmpc /etc/fcmpc/signing.key && chmod 0600 /etc/fcmpc/signing.key
install -o root -g root -m 0644 "$REPO/deploy/fcmpc-companion.service" /etc/systemd/system/fcmpc-companion.service
systemctl daemon-reload
systemctl enable fcmpc-companion.service
echo "edit /etc/fcmpc/companion.env and /etc/fcmpc/companion.parm, then: systemctl start fcmpc-companion"
