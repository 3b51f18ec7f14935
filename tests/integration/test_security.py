"""The secured bus on a real zenoh router on 127.0.0.1: who may connect, and what a robot may publish."""

from __future__ import annotations

import dataclasses
import json
import os
import time
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.x509.oid import NameOID

from tests.conftest import run_pixelswarm
from transport.bus import Bus
from transport.codec import Goals
from transport.keys import Keys
from transport.security import (
    AUTH_MODES,
    SecurityError,
    client_config,
    make_certificates,
    roles,
    router_config,
)
from transport.session import TransportError, ZenohSettings, free_port, open_session

ROBOTS = 6
KEYS = Keys("default")
REFUSED_MS = 1000  # a refused client gives up after this; the same timeout lets a legitimate one in


def _open(settings: ZenohSettings):
    return open_session(dataclasses.replace(settings, connect_timeout_ms=REFUSED_MS))


@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> Path:
    return make_certificates(tmp_path_factory.mktemp("security") / "certs", ROBOTS)


def _router(certs: Path, auth: str):
    endpoint = f"tls/127.0.0.1:{free_port()}"
    return endpoint, open_session(router_config(certs, endpoint, auth=auth))


@pytest.fixture(params=AUTH_MODES)
def secured(certs, request):
    """A router enforcing the access rules, known by certificate (tls) or by user name (usrpwd)."""
    endpoint, session = _router(certs, request.param)
    yield request.param, endpoint
    session.close()


@pytest.fixture
def tls_router(certs):
    endpoint, session = _router(certs, "tls")
    yield endpoint
    session.close()


def _client_file(tmp_path: Path, tls: dict, usrpwd: dict | None = None) -> str:
    """A hand-made client configuration (what an outsider would try)."""
    conf: dict = {"transport": {"link": {"tls": tls}}}
    if usrpwd:
        conf["transport"]["auth"] = {"usrpwd": usrpwd}
    path = tmp_path / "outsider.json5"
    path.write_text(json.dumps(conf))
    return str(path)


def _wait_until(predicate, timeout: float = 5.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.02)
    return predicate()


def test_certificates_name_their_roles_and_chain_to_the_ca(certs):
    ca = x509.load_pem_x509_certificate((certs / "ca.pem").read_bytes())
    for role in roles(ROBOTS):
        cert = x509.load_pem_x509_certificate((certs / f"{role}.pem").read_bytes())
        assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == role
        cert.verify_directly_issued_by(ca)
        assert (certs / f"{role}-key.pem").stat().st_mode & 0o077 == 0  # private keys readable by the owner only
    assert (certs / "usrpwd" / "credentials.txt").stat().st_mode & 0o077 == 0
    assert (certs / "robot-3.json5").is_file() and not (certs / "router-key.pem").stat().st_mode & 0o077


def test_a_session_without_a_certificate_cannot_connect(tls_router, tmp_path, certs):
    anonymous = _client_file(tmp_path, {"root_ca_certificate": str(certs / "ca.pem")})
    with pytest.raises(TransportError):
        _open(ZenohSettings(connect=[tls_router], config_file=anonymous))
    _open(client_config(certs, "robot-3", tls_router)).close()


def test_a_certificate_from_another_ca_cannot_connect(tls_router, tmp_path, certs):
    other = make_certificates(tmp_path / "other", 4)
    forged = _client_file(
        tmp_path,
        {
            "root_ca_certificate": str(certs / "ca.pem"),  # trusts our router, presents a stranger's robot-3
            "connect_certificate": str(other / "robot-3.pem"),
            "connect_private_key": str(other / "robot-3-key.pem"),
            "enable_mtls": True,
        },
    )
    with pytest.raises(TransportError):
        _open(ZenohSettings(connect=[tls_router], config_file=forged))
    _open(client_config(certs, "robot-3", tls_router)).close()


def test_a_wrong_password_cannot_connect(certs, tmp_path):
    endpoint, router = _router(certs, "usrpwd")
    try:
        tls = {"root_ca_certificate": str(certs / "ca.pem")}
        for user, password in (("robot-3", "not-the-password"), ("intruder", "secret")):
            wrong = _client_file(tmp_path, tls, {"user": user, "password": password})
            with pytest.raises(TransportError):
                _open(ZenohSettings(connect=[endpoint], config_file=wrong))
        _open(client_config(certs, "robot-3", endpoint, auth="usrpwd")).close()
    finally:
        router.close()


def test_a_robot_cannot_publish_goals_or_command_another_robot(secured, certs):
    auth, endpoint = secured

    def bus(role: str) -> Bus:
        return Bus(client_config(certs, role, endpoint, auth=auth))

    with bus("recorder") as recorder, bus("world") as world, bus("coordinator") as coordinator, bus("robot-3") as robot:
        everything = recorder.subscribe_raw(KEYS.everything)
        commands = world.subscribe_raw(KEYS.all_of("cmd"))
        alive = coordinator.watch_alive("agent")
        heard: dict[str, list] = {"recorder": [], "world": [], "alive": []}

        def listen() -> dict[str, set]:
            heard["recorder"] += [key for key, _, _ in everything.drain()]
            heard["world"] += [key for key, _, _ in commands.drain()]
            heard["alive"] += [ident for _, ident, _, _, _ in alive.drain()]
            return {name: set(keys) for name, keys in heard.items()}

        def probe() -> bool:
            robot.put(KEYS.cmd(3), b"probe")
            return KEYS.cmd(3) in listen()["world"] & listen()["recorder"]

        # Until both subscriptions are routed: robot 3's own command reaches the world and the recorder.
        assert _wait_until(probe)
        # KEYS.event: the run's end and the world's report are the services' (a robot's statistics: KEYS.stats(3))
        forged = [KEYS.goals(9), KEYS.cmd(5), KEYS.states(5), KEYS.state((0, 0), 5), KEYS.poses, KEYS.clock, KEYS.event]
        for key in forged:
            robot.put(key, b"forged")
        robot.declare_alive("agent", 5)
        # Robot 3's own state and token go after its forgeries on the same link: once they have
        # arrived, any forgery the router let through has arrived before them.
        robot.put(KEYS.stats(3), b"own statistics")
        robot.put(KEYS.state((0, 0), 3), b"own")
        robot.declare_alive("agent", 3)
        coordinator.put(KEYS.goals(1), b"goal set")
        assert _wait_until(lambda: {KEYS.stats(3), KEYS.state((0, 0), 3), KEYS.goals(1)} <= listen()["recorder"])
        assert _wait_until(lambda: "3" in listen()["alive"])
        got = listen()
        assert not set(forged) & (got["recorder"] | got["world"]), got
        assert "5" not in got["alive"]


def test_certs_makes_a_folder_that_a_router_and_robots_use(tmp_path):
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    result = run_pixelswarm("certs", str(tmp_path / "certs"), "--robots", "2", "--listen", endpoint)
    assert result.returncode == 0, result.stderr
    folder = Path(result.stdout.strip())
    router = open_session(ZenohSettings(mode="router", config_file=str(folder / "router.json5")))
    try:
        # the endpoint written by `certs` is enough: no -e needed
        with Bus(ZenohSettings(config_file=str(folder / "robot-1.json5"))) as robot:
            assert robot.session is not None
    finally:
        router.close()
    assert not [p for p in tmp_path.iterdir() if p.name != "certs"]  # no staging folder left behind


@pytest.mark.parametrize(
    "args, message",
    [
        (["--robots", "0"], "at least 1"),
        (["--robots", "three"], "whole number"),
        (["--robots", "2", "--listen", "tcp/127.0.0.1:7447"], "tls/HOST:PORT"),
    ],
)
def test_certs_bad_input_exits_2(tmp_path, args, message):
    result = run_pixelswarm("certs", str(tmp_path / "certs"), *args, timeout=60)
    assert result.returncode == 2
    assert message in result.stderr and len(result.stderr.strip().splitlines()) == 1
    assert "Traceback" not in result.stderr and list(tmp_path.iterdir()) == []


def test_certs_refuses_an_unwritable_or_full_folder(tmp_path):
    (tmp_path / "a-file").write_text("not a folder")
    full = tmp_path / "full"
    full.mkdir()
    (full / "keep.txt").write_text("mine")
    result = run_pixelswarm("certs", str(tmp_path / "a-file" / "certs"), "--robots", "2", timeout=60)
    assert result.returncode == 2 and "cannot write" in result.stderr and "Traceback" not in result.stderr
    with pytest.raises(SecurityError, match="already holds files"):
        make_certificates(full, 2)
    assert sorted(os.listdir(tmp_path)) == ["a-file", "full"] and os.listdir(full) == ["keep.txt"]
    make_certificates(full, 2, overwrite=True)  # asked: the old contents go, the new folder is whole
    assert not (full / "keep.txt").exists() and (full / "robot-1.pem").is_file()
    assert sorted(os.listdir(tmp_path)) == ["a-file", "full"]


def test_the_routers_own_session_is_not_subject_to_the_rules(certs):
    """A run's launcher embeds the router and records and ends the run from its session."""
    endpoint = f"tls/127.0.0.1:{free_port()}"
    with Bus(router_config(certs, endpoint)) as launcher, Bus(client_config(certs, "world", endpoint)) as world:
        everything = launcher.subscribe_raw(KEYS.everything)
        events = world.subscribe_raw(KEYS.event)
        with Bus(client_config(certs, "robot-2", endpoint)) as robot:

            def routed() -> bool:
                launcher.put(KEYS.event, b"end")
                robot.put(KEYS.cmd(2), b"own")
                return bool(events.drain()) and KEYS.cmd(2) in {key for key, _, _ in everything.drain()}

            assert _wait_until(routed)


def test_only_the_coordinator_answers_a_robots_question_for_the_goal_set(secured, certs):
    auth, endpoint = secured

    def bus(role: str) -> Bus:
        return Bus(client_config(certs, role, endpoint, auth=auth))

    with bus("coordinator") as coordinator, bus("robot-5") as impostor, bus("robot-3") as robot:
        states = robot.subscribe_raw(KEYS.all_of("state"))
        impostor.serve(KEYS.all_of("goals"), lambda: [(KEYS.goals(666), Goals(666, 0).encode())])

        def impostor_heard() -> bool:  # its state follows its queryable on one link: the router has seen both
            impostor.put(KEYS.state((0, 0), 5), b"own")
            return bool(states.drain())

        assert _wait_until(impostor_heard)
        coordinator.serve(KEYS.all_of("goals"), lambda: [(KEYS.goals(4), Goals(4, 0).encode())])
        answers: list = []
        assert _wait_until(lambda: answers.extend(robot.query(KEYS.all_of("goals"), Goals, timeout=0.5)) or answers)
        assert {msg.epoch for _, msg in answers} == {4}


def test_a_busy_tls_port_is_said_with_a_tls_endpoint_to_try_instead(tls_router, certs):
    """The hint keeps the endpoint's protocol: a secured router listens on tls (it said -l tcp/...)."""
    result = run_pixelswarm("router", "--zenoh-config", str(certs / "router.json5"), "-l", tls_router, timeout=60)
    assert result.returncode == 2 and "Traceback" not in result.stderr
    line = result.stderr.strip()
    assert "\n" not in line and f"on {tls_router}: address already in use" in line, line
    assert line.endswith("choose another with -l tls/127.0.0.1:PORT"), line


def test_a_router_whose_configuration_listens_nowhere_is_refused(tmp_path):
    """Certificates made without --listen give the router no endpoint (as this file has none): `pixelswarm
    router --zenoh-config router.json5` said it was listening and listened nowhere."""
    config = tmp_path / "router.json5"
    config.write_text('{ mode: "router", listen: { endpoints: [] }, scouting: { multicast: { enabled: false } } }\n')
    result = run_pixelswarm("router", "--zenoh-config", str(config), timeout=60)
    assert result.returncode == 2 and result.stdout == "", (result.stdout, result.stderr)
    assert result.stderr.strip().endswith("names no endpoint to listen on: give -l tls/HOST:PORT"), result.stderr
