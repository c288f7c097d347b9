"""deploy/: the systemd unit says what issue 10 asks, and the real companion process speaks sd_notify
(READY once, WATCHDOG at half of WatchdogSec) to a real Unix socket; the BlueOS extension's image
carries the metadata BlueOS reads, and its command runs the companion against BlueOS's endpoint."""
from __future__ import annotations

import configparser
import os
import socket
import subprocess
import sys
from pathlib import Path

from tests.ports import free_port

REPO = Path(__file__).resolve().parents[1]
UNIT = REPO / "deploy" / "fcmpc-companion.service"


def _unit() -> configparser.ConfigParser:
    parser = configparser.ConfigParser(strict=False, interpolation=None)
    parser.optionxform = str
    parser.read(UNIT)
    return parser


def test_unit_restarts_on_failure_with_a_watchdog_as_a_non_root_user():
    service = _unit()["Service"]
    assert service["Type"] == "notify" and service["Restart"] == "on-failure"
    assert int(service["WatchdogSec"]) > 0
    assert service["User"] not in ("", "root") and service["Group"] not in ("", "root")
    assert "--signing-key /etc/fcmpc/signing.key" in service["ExecStart"]
    assert service["UMask"] == "0077"
    install = (REPO / "deploy" / "install.sh").read_text()
    assert "chmod 0600 /etc/fcmpc/signing.key" in install


def test_the_running_companion_says_ready_and_feeds_the_watchdog(tmp_path):
    path = str(tmp_path / "notify")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(60.0)
    port = free_port()
    env = dict(os.environ, PYTHONPATH=str(REPO), NOTIFY_SOCKET=path, WATCHDOG_USEC="400000")
    proc = subprocess.Popen([sys.executable, "-m", "companion.app", "--connect", f"udp:127.0.0.1:{port}",
                             "--params", str(tmp_path / "c.parm"), "--params-create", "--log-dir",
                             str(tmp_path / "log"), "--quiet", "--max-wall-s", "120"],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        assert sock.recv(100) == b"READY=1"
        feeds = [sock.recv(100) for _ in range(3)]      # no flight controller at all: the loop still runs
        assert feeds == [b"WATCHDOG=1"] * 3
    finally:
        proc.terminate()
        proc.wait(timeout=30)
        sock.close()


# --- BlueOS extension (deploy/blueos/): the metadata BlueOS reads, checked against its documented format
# (bluerobotics/BlueOS-Extensions-Repository README "Data in DockerHub" and blueos_repository/extension/models.py)

BLUEOS = REPO / "deploy" / "blueos"
BLUEOS_LABELS = ("version", "permissions", "authors", "company", "readme", "links", "type", "tags", "requirements")
BLUEOS_TYPES = ("device-integration", "example", "theme", "other", "tool")
# BlueOS's default MAVLink endpoint for onboard programs: "Internal Link", a TCP server on the host's
# 127.0.0.1:5777, persistent and protected (core/services/ardupilot_manager/autopilot_manager.py)
BLUEOS_INTERNAL_LINK = ("127.0.0.1", 5777)


def _dockerfile():
    from dockerfile_parse import DockerfileParser

    return DockerfileParser(str(BLUEOS / "Dockerfile"), build_args={"GITHUB_REPOSITORY": "someone/fcmpc"})


def _exec_form(parser, instruction: str) -> list[str]:
    import json

    values = [item["value"] for item in parser.structure if item["instruction"] == instruction]
    assert len(values) == 1, f"one {instruction}"
    return json.loads(values[0])      # exec form: a JSON list, so the companion is PID 1 and gets SIGTERM


def _command() -> list[str]:
    parser = _dockerfile()
    return _exec_form(parser, "ENTRYPOINT") + _exec_form(parser, "CMD")


def test_blueos_labels_follow_the_extension_format():
    import json
    import re

    labels = _dockerfile().labels
    assert set(BLUEOS_LABELS) <= set(labels)
    setup = configparser.ConfigParser()
    setup.read(REPO / "setup.cfg")
    assert labels["version"] == setup["metadata"]["version"]          # the tag BlueOS shows is the package's
    assert re.fullmatch(r"\d+\.\d+\.\d+(-[0-9A-Za-z.-]+)?", labels["version"])   # semver, as the store asks
    authors = json.loads(labels["authors"])
    assert authors and all(set(author) == {"name", "email"} for author in authors)
    assert {"name", "about", "email"} <= set(json.loads(labels["company"]))
    assert labels["type"] in BLUEOS_TYPES
    tags = json.loads(labels["tags"])
    assert 0 < len(tags) <= 10 and all(re.fullmatch(r"[a-z0-9]+(-[a-z0-9]+)*", tag) for tag in tags)
    assert re.fullmatch(r"core >= \d+(\.\d+)*", labels["requirements"])
    assert labels["readme"] == f"https://raw.githubusercontent.com/someone/fcmpc/v{labels['version']}/docs/deploy.md"
    assert (REPO / "docs" / "deploy.md").is_file()
    assert all(url.startswith("https://") for url in json.loads(labels["links"]).values())
    registration = json.loads((BLUEOS / "metadata.json").read_text())    # the store's repos/<company>/<ext>/
    assert set(registration) == {"name", "website", "docker", "description"}
    assert all(isinstance(value, str) and value for value in registration.values())


def test_blueos_permissions_are_a_container_payload_that_matches_the_command():
    import json
    import re
    from urllib.parse import urlsplit

    permissions = json.loads(_dockerfile().labels["permissions"])     # strict JSON (the store reads JSON5)
    assert set(permissions) <= {"ExposedPorts", "HostConfig", "Env"}  # Docker's ContainerCreate payload
    exposed = permissions.get("ExposedPorts", {})
    assert all(re.fullmatch(r"\d+/(tcp|udp)", port) and spec == {} for port, spec in exposed.items())
    host = permissions["HostConfig"]
    bindings = host.get("PortBindings", {})
    assert set(bindings) == set(exposed)
    assert all(isinstance(b, list) and all(set(x) <= {"HostPort", "HostIp"} for x in b) for b in bindings.values())
    binds = dict(bind.split(":")[:2] for bind in host["Binds"])
    assert all(source.startswith("/usr/blueos/extensions/") for source in binds)

    command = _command()
    assert command[0] == "fcmpc-companion"
    setup = configparser.ConfigParser()
    setup.read(REPO / "setup.cfg")
    assert "fcmpc-companion = companion.app:main" in setup["options.entry_points"]["console_scripts"]
    from companion.app import build_parser

    parser = build_parser()
    args = parser.parse_args(command[1:])       # the companion's own parser accepts the command
    # MAVLink: a client of BlueOS's Internal Link, on the host's loopback, hence the host's network
    scheme, _, where = args.connect.partition(":")
    host_name, port = where.rsplit(":", 1)
    assert scheme == "tcp" and (host_name, int(port)) == BLUEOS_INTERNAL_LINK
    assert host["NetworkMode"] == "host"
    # what the command serves is what is exposed: a listening link (udpin/tcpin) and the status page
    served = set()
    if scheme in ("udpin", "udp", "tcpin"):
        served.add(f"{port}/{'tcp' if scheme == 'tcpin' else 'udp'}")
    http = getattr(args, "http", None)
    if http:
        served.add(f"{urlsplit('//' + http).port}/tcp")
    assert served == set(exposed)
    # records and parameters outlive the container: both in a bind-mounted folder
    for path in (args.params, args.log_dir):
        assert any(path == target or path.startswith(target + "/") for target in binds.values()), path


def test_the_blueos_command_runs_the_companion_which_speaks_to_the_endpoint(tmp_path):
    """The image's command as it is, with the container's /data and BlueOS's Internal Link mapped
    onto a temporary folder and a loopback TCP server: the companion starts with the defaults it
    creates, connects, and its HEARTBEAT (component 191) reaches BlueOS's end of the link."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    data = str(tmp_path / "data")
    server = socket.create_server(("127.0.0.1", free_port()))
    server.settimeout(60.0)
    internal_link = "{}:{}".format(*BLUEOS_INTERNAL_LINK)
    command = [arg.replace("/data", data).replace(internal_link, "127.0.0.1:{}".format(server.getsockname()[1]))
               for arg in _command()[1:]]
    env = dict(os.environ, PYTHONPATH=str(REPO))
    proc = subprocess.Popen([sys.executable, "-m", "companion.app", *command, "--max-wall-s", "120"],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        link, _ = server.accept()
        link.settimeout(60.0)
        decoder = mavlink.MAVLink(None)
        heartbeat = None
        while heartbeat is None:
            chunk = link.recv(2048)
            assert chunk, "the companion closed the link"
            for message in decoder.parse_buffer(chunk) or []:
                if message.get_type() == "HEARTBEAT":
                    heartbeat = message
        assert heartbeat.get_srcComponent() == 191
        assert Path(data, "logs").is_dir()
        link.close()
    finally:
        proc.terminate()
        proc.wait(timeout=30)
        server.close()
