"""A secured bus: one certificate authority per deployment, a certificate per role, and access control.

`make_certificates(dir, robots)` writes the folder of docs/security.md. The access rules follow the key
schema (transport/keys.py) and deny by default; the router enforces them, so every session goes through it."""

from __future__ import annotations

import datetime
import json
import os
import secrets
import shutil
import tempfile
from pathlib import Path

from .keys import Keys
from .session import ZenohSettings

SERVICES = ("coordinator", "tracker", "world", "recorder", "observer")
OBSERVER = "observer"  # a viewer watching a run (`pixelswarm view --connect`): reads the display, never publishes
ROUTER = "router"
AUTH_MODES = ("tls", "usrpwd")
LOOPBACK_NAMES = ("127.0.0.1", "localhost")  # the router certificate always names these
USRPWD = "usrpwd"
MANIFEST = "roles.json"


class SecurityError(ValueError):
    """Bad input for the secured bus (folder exists, unknown role, no robots): one line for the user."""


def robot_role(robot: int) -> str:
    return f"robot-{robot}"


def roles(robots: int) -> list[str]:
    """Every role of a deployment with robots 0..robots-1, the router last."""
    return [*SERVICES, *(robot_role(i) for i in range(robots)), ROUTER]


# What each grant of _grants lets a subject do, as the router's rules: (what, messages, flow); flows are
# seen from the router: what a client sends is ingress, what it receives egress.
_GRANT_RULES: dict[str, tuple[tuple[str, list[str], str], ...]] = {
    "put": (("publishes", ["put"], "ingress"),),
    # a subscription is declared in, and its samples go out
    "read": (("subscribes", ["declare_subscriber"], "ingress"), ("receives", ["put"], "egress")),
    "token": (("declares alive", ["liveliness_token"], "ingress"),),
    "watch": (
        ("watches", ["declare_liveliness_subscriber", "liveliness_query"], "ingress"),
        ("sees alive", ["liveliness_token"], "egress"),
    ),
    "query": (("asks", ["query"], "ingress"), ("hears answers", ["reply"], "egress")),
    "serve": (("serves", ["declare_queryable", "reply"], "ingress"), ("is asked", ["query"], "egress")),
}


def _grants(prefix: str, **grants: list[str]) -> list[dict]:
    """The router's allow rules for what one subject may do (``put=[key expressions]``, ...)."""
    return [
        {"id": f"{prefix} {what}", "permission": "allow", "flows": [flow], "messages": messages, "key_exprs": exprs}
        for grant, rules in _GRANT_RULES.items()
        if (exprs := list(grants.get(grant, ())))
        for what, messages, flow in rules
    ]


def _service_grants(keys: Keys) -> dict[str, list[dict]]:
    """What each service may do; all watch who is alive, and those that run the show declare themselves alive."""
    grants: dict[str, dict[str, list[str]]] = {
        "coordinator": {
            "put": [keys.all_of("goals")],
            "serve": [keys.all_of("goals")],
            "query": [keys.run_goals],  # restarted mid-run: the newest goal set, from the launcher
            # the agents' events: a lock-step host that gave up a block asks for a new goal set
            "read": [keys.clock, keys.all_of("pose"), keys.poses, keys.agents_events],
        },
        "tracker": {"put": [keys.all_of("pose"), keys.poses], "read": [keys.clock]},
        # the simulated world is a simulation's tracker, and its scripted obstacles broadcast states like robots
        "world": {
            "put": [keys.clock, keys.all_of("pose"), keys.poses, keys.all_of("state"), keys.all_of("sim"), keys.event],
            "read": [keys.all_of("cmd"), keys.event, keys.all_of("goals")],  # goals: each tick names the newest
        },
        "recorder": {"read": [keys.everything]},
        # a viewer only reads, so joining costs the run's processes nothing
        OBSERVER: {"read": [keys.all_of("sim"), keys.all_of("state"), keys.all_of("goals"), keys.clock, keys.event]},
    }
    for role in ("coordinator", "tracker", "world"):
        grants[role]["token"] = [keys.alive_all(role)]
    return {role: _grants(role, **grant, watch=[keys.alive_all()]) for role, grant in grants.items()}


def access_control(robots: int, *, by: str = "cert_common_names", display: str = "default") -> dict:
    """Zenoh `access_control` for a router: default deny, and every role's grants; ``by``: how the router
    knows a role, "cert_common_names" (mutual TLS) or "usernames" (user/password)."""
    if robots < 1:
        raise SecurityError(f"robots must be at least 1, not {robots}")
    keys = Keys(display)
    rules: list[dict] = []
    subjects: list[dict] = []
    policies: list[dict] = []

    def grant(subject_id: str, names: list[str], grants: list[dict]) -> None:
        rules.extend(grants)
        subjects.append({"id": subject_id, by: names})
        policies.append({"id": subject_id, "rules": [g["id"] for g in grants], "subjects": [subject_id]})

    for role, grants in _service_grants(keys).items():
        grant(role, [role], grants)
    for i in range(robots):  # what only robot i may do: publish its own keys, hear its own pose and command
        role = robot_role(i)
        put = [keys.state_of(i), keys.states(i), keys.cmd(i), keys.auction_of(i), keys.boards_of(i), keys.stats(i)]
        grant(role, [role], _grants(role, put=put, read=[keys.pose(i), keys.cmd(i)], token=[keys.alive("agent", i)]))
    # what every robot may read: neighbours' states, poses frames, goals, bids, the clock
    heard = [keys.poses, *(keys.all_of(kind) for kind in ("state", "goals", "auction", "boards")), keys.clock]
    every = _grants("robots", read=heard, query=[keys.all_of("goals")], watch=[keys.alive_all()])
    grant("robots", [robot_role(i) for i in range(robots)], every)
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def _common(mode: str, connect: list[str], listen: list[str]) -> dict:
    # Listen always explicit (zenoh's default is every interface), no scouting: only the router given.
    conf: dict = {"mode": mode, "listen": {"endpoints": listen}, "scouting": {"multicast": {"enabled": False}}}
    if connect:
        conf["connect"] = {"endpoints": connect}
    return conf


def _client_dict(directory: Path, role: str, connect: list[str], auth: str, password: str | None = None) -> dict:
    conf = _common("client", connect, [])
    tls: dict = {"root_ca_certificate": str(directory / "ca.pem")}
    if auth == "tls":
        tls |= {
            "connect_certificate": str(directory / f"{role}.pem"),
            "connect_private_key": str(directory / f"{role}-key.pem"),
            "enable_mtls": True,  # without it a client never presents its certificate
        }
    else:
        conf["transport"] = {"auth": {"usrpwd": {"user": role, "password": password}}}
    conf.setdefault("transport", {})["link"] = {"tls": tls}
    return conf


def _router_dict(directory: Path, listen: list[str], auth: str, robots: int, display: str) -> dict:
    conf = _common("router", [], listen)
    tls = {
        "root_ca_certificate": str(directory / "ca.pem"),
        "listen_certificate": str(directory / f"{ROUTER}.pem"),
        "listen_private_key": str(directory / f"{ROUTER}-key.pem"),
        "enable_mtls": auth == "tls",
    }
    conf["transport"] = {"link": {"tls": tls}}
    if auth == "usrpwd":
        conf["transport"]["auth"] = {"usrpwd": {"dictionary_file": str(directory / USRPWD / "credentials.txt")}}
    by = "cert_common_names" if auth == "tls" else "usernames"
    conf["access_control"] = access_control(robots, by=by, display=display)
    return conf


def _folder(directory: str | Path, display: str) -> tuple[Path, dict]:
    """A folder of access rules, resolved, and its manifest, if it is one, readable, for ``display``."""
    directory = Path(directory).resolve()
    if not directory.is_dir():
        raise SecurityError(f"{directory} is not a folder; make one with `pixelswarm certs DIR --robots N`")
    if not os.access(directory, os.R_OK | os.X_OK):
        raise SecurityError(f"cannot read {directory}")
    manifest = _manifest(directory)
    made_for = manifest.get("display", "default")
    if made_for != display:
        raise SecurityError(f"{directory} holds access rules for display {made_for!r}, not {display!r}")
    return directory, manifest


def _manifest(directory: Path) -> dict:
    path = directory / MANIFEST
    try:
        manifest = json.loads(path.read_text())
    except FileNotFoundError:
        raise SecurityError(
            f"{directory} holds no certificates made by `pixelswarm certs` ({MANIFEST} missing)"
        ) from None
    except OSError as err:
        raise SecurityError(f"cannot read {path}: {err.strerror or err}") from None
    except ValueError:
        manifest = None
    if not isinstance(manifest, dict) or not isinstance(manifest.get("robots"), int):
        raise SecurityError(f"{path} is not a manifest written by `pixelswarm certs`")
    return manifest


def _role_file(directory: str | Path, role: str, auth: str) -> str:
    """The role's configuration file in a folder made by make_certificates."""
    if auth not in AUTH_MODES:
        raise SecurityError(f"auth must be one of {', '.join(AUTH_MODES)}, not {auth!r}")
    directory = Path(directory).resolve()
    robots = _manifest(directory)["robots"]
    if role not in roles(robots):
        raise SecurityError(f"no role {role!r} in {directory} (robots 0..{robots - 1})")
    return str(directory / (USRPWD if auth == "usrpwd" else "") / f"{role}.json5")


def _unreadable(directory: Path, role: str) -> str | None:
    """The first file a TLS session of this role reads that cannot be read, if any."""
    files = ["ca.pem", f"{role}.json5", f"{role}.pem", f"{role}-key.pem"]
    return next((name for name in files if not os.access(directory / name, os.R_OK)), None)


def check_folder(directory: str | Path, robots: int, *, display: str = "default") -> Path:
    """The folder, resolved, if a run of robots 0..robots-1 on ``display`` can use it (its rules cover
    them, and the files of the router, coordinator, world and robots are readable); else SecurityError."""
    directory, manifest = _folder(directory, display)
    if manifest["robots"] < robots:
        raise SecurityError(
            f"{directory} was made for {manifest['robots']} robots and this run has {robots}; "
            f"make a folder for them with `pixelswarm certs DIR --robots {robots}`"
        )
    for role in [ROUTER, "coordinator", "world", *(robot_role(i) for i in range(robots))]:
        if (name := _unreadable(directory, role)) is not None:
            raise SecurityError(f"cannot read {directory / name} (the {role}'s)")
    return directory


def check_role(directory: str | Path, role: str, *, display: str = "default") -> Path:
    """The folder, resolved, if a session of ``role`` on ``display`` can open from it (its files are
    readable), else SecurityError in one line; a folder made before the role existed says so."""
    directory, _ = _folder(directory, display)
    if (name := _unreadable(directory, role)) is None:
        return directory
    if not (directory / name).exists() and role in SERVICES:
        raise SecurityError(
            f"{directory} has no {role} role ({name} missing): it was made before the role existed; "
            "make the folder again with `pixelswarm certs`"
        )
    raise SecurityError(f"cannot read {directory / name} (the {role}'s)")


def _endpoints(endpoints: str | list[str] | None) -> list[str]:
    return [endpoints] if isinstance(endpoints, str) else list(endpoints or [])


def router_config(directory: str | Path, listen: str | list[str] | None = None, *, auth: str = "tls") -> ZenohSettings:
    """A router enforcing the folder's access rules, on ``listen`` (tls/HOST:PORT; default: the folder's)."""
    return ZenohSettings(mode="router", listen=_endpoints(listen), config_file=_role_file(directory, ROUTER, auth))


def client_config(
    directory: str | Path, role: str, connect: str | list[str] | None = None, *, auth: str = "tls"
) -> ZenohSettings:
    """A client session as ``role``, to the router at ``connect`` (tls/HOST:PORT; default: the folder's)."""
    if role == ROUTER:
        raise SecurityError("the router is not a client role")
    return ZenohSettings(mode="client", connect=_endpoints(connect), config_file=_role_file(directory, role, auth))


def _write(path: Path, data: bytes | str, secret: bool = False) -> None:
    path.write_bytes(data.encode() if isinstance(data, str) else data)
    if secret:
        path.chmod(0o600)


def _json5(conf: dict, what: str) -> str:
    return f"// {what} (written by `pixelswarm certs`)\n" + json.dumps(conf, indent=2) + "\n"


def _tls_host(endpoint: str) -> str:
    """HOST of tls/HOST:PORT ([v6] brackets dropped); SecurityError for anything else."""
    proto, _, address = endpoint.partition("/")
    host, _, port = address.split("#", 1)[0].rpartition(":")
    if proto != "tls" or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise SecurityError(f"the router endpoint must be tls/HOST:PORT, not {endpoint!r}")
    return host.strip("[]")


def make_certificates(
    directory: str | Path, robots: int, *, connect: str | None = None, display: str = "default", overwrite: bool = False
) -> Path:
    """Write the folder (whole or not at all; a non-empty one replaced only with ``overwrite``); its path.

    ``connect``: the router endpoint (tls/HOST:PORT) in every configuration, HOST also named by the router
    certificate; without it, no endpoint, and the certificate names only 127.0.0.1, localhost and the router's role.
    """
    final = _folder_to_write(directory, robots, display, overwrite)
    hosts = [*LOOPBACK_NAMES, *([_tls_host(connect)] if connect else [])]
    staging = Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".partial", dir=final.parent))
    try:
        _write_folder(staging, final, robots, hosts, [connect] if connect else [], display)
        _replace(staging, final)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return final


def _folder_to_write(directory: str | Path, robots: int, display: str, overwrite: bool) -> Path:
    """The folder make_certificates may write, absolute; SecurityError for what it may not."""
    if robots < 1:
        raise SecurityError(f"robots must be at least 1, not {robots}")
    Keys(display)  # the display name must be one the key schema accepts
    final = Path(directory).resolve()
    if final.exists() and not final.is_dir():
        raise SecurityError(f"{final} exists and is not a folder")
    if final.is_dir() and any(final.iterdir()) and not overwrite:
        raise SecurityError(f"{final} already holds files; choose another folder or replace it (--force)")
    parent = final.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise SecurityError(f"cannot write into {parent}")
    return final


def _write_folder(
    staging: Path, final: Path, robots: int, hosts: list[str], connect_list: list[str], display: str
) -> None:
    """Everything of the folder into ``staging``; the configurations name their files at ``final``."""
    from . import certificates  # here: of the commands, only `pixelswarm certs` loads cryptography

    now = datetime.datetime.now(datetime.UTC)
    ca_key, ca = certificates.authority(now)
    _write(staging / "ca.pem", certificates.pem(ca))
    _write(staging / "ca-key.pem", certificates.pem_key(ca_key), secret=True)
    (staging / USRPWD).mkdir()
    passwords = {}
    for role in roles(robots):
        # the router's certificate also names its hosts and serves TLS; the others only prove who connects
        router = role == ROUTER
        key, cert = certificates.role_certificate(role, [*hosts, role] if router else [role], router, ca_key, ca, now)
        _write(staging / f"{role}.pem", certificates.pem(cert))
        _write(staging / f"{role}-key.pem", certificates.pem_key(key), secret=True)
        if router:
            continue
        passwords[role] = secrets.token_urlsafe(24)
        for auth, where, password in (("tls", staging, None), ("usrpwd", staging / USRPWD, passwords[role])):
            conf = _client_dict(final, role, connect_list, auth, password)
            _write(where / f"{role}.json5", _json5(conf, f"client {role}"), secret=password is not None)
    _write(staging / USRPWD / "credentials.txt", "".join(f"{r}:{p}\n" for r, p in passwords.items()), secret=True)
    for auth, where in (("tls", staging), ("usrpwd", staging / USRPWD)):
        conf = _router_dict(final, connect_list, auth, robots, display)
        _write(where / "router.json5", _json5(conf, f"router, {auth}"))
    _write(staging / MANIFEST, json.dumps({"robots": robots, "display": display}) + "\n")


def _replace(staging: Path, final: Path) -> None:
    """Rename the finished folder into place (an old one moved aside first, removed after)."""
    old = None
    if final.is_dir() and any(final.iterdir()):
        old = final.with_name(f".{final.name}.old-{secrets.token_hex(4)}")
        final.rename(old)
    elif final.is_dir():
        final.rmdir()
    staging.chmod(0o700)
    staging.rename(final)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
