"""Zenoh session configuration: embedded router, client and peer modes, zenoh-style flags.

Multicast scouting is off unless asked for, and the embedded router listens on loopback only, so
nothing leaves the machine unless the user points it elsewhere with -e/-l.
"""

from __future__ import annotations

import json
import re
import textwrap
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import zenoh

if TYPE_CHECKING:
    import argparse

MODES = ("router", "peer", "client")


class TransportError(RuntimeError):
    """A session could not be opened (port in use, router unreachable, bad endpoint)."""


@dataclass
class ZenohSettings:
    mode: str = "client"
    connect: list[str] = field(default_factory=list)
    listen: list[str] = field(default_factory=list)
    multicast_scouting: bool = False
    lease_ms: int = 2000  # a frozen process is declared dead after ~0.75 x lease (zenoh default 10 s)
    connect_timeout_ms: int = 5000  # a client that cannot reach (or is refused by) its router fails after this
    config_file: str | None = None  # a zenoh JSON5 file (e.g. a role's from `pixelswarm certs`); the rest overrides it

    def to_config(self) -> zenoh.Config:
        if self.mode not in MODES:
            raise TransportError(f"zenoh mode must be one of {', '.join(MODES)}, not {self.mode!r}")
        conf = _config_file(self.config_file) if self.config_file else zenoh.Config()
        conf.insert_json5("mode", json.dumps(self.mode))
        if self.connect:
            conf.insert_json5("connect/endpoints", json.dumps(self.connect))
        # listen always explicit (zenoh's default is every interface), unless a configuration file sets it
        if self.listen or not self.config_file:
            conf.insert_json5("listen/endpoints", json.dumps(self.listen))
        conf.insert_json5("scouting/multicast/enabled", json.dumps(self.multicast_scouting))
        conf.insert_json5("transport/link/tx/lease", str(self.lease_ms))
        if self.mode == "client":  # a client that loses its router should fail loudly, not wait forever
            conf.insert_json5("connect/timeout_ms", str(self.connect_timeout_ms))
        elif not (self.multicast_scouting or self.connect or self.config_file):
            conf.insert_json5("scouting/delay", "0")  # nobody to scout for: open would wait out the delay
        return conf

    def to_args(self) -> list[str]:
        """The same settings as command-line flags, for child processes."""
        args = ["-m", self.mode]
        for e in self.connect:
            args += ["-e", e]
        for e in self.listen:
            args += ["-l", e]
        if not self.multicast_scouting:
            args.append("--no-multicast-scouting")
        if self.config_file:
            args += ["--zenoh-config", self.config_file]
        return args


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port that is free on loopback right now."""
    import socket  # here: a robot's process never needs it

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind((host, 0))
        return sock.getsockname()[1]


def listening(port: int, host: str = "127.0.0.1") -> bool:
    """Whether something accepts TCP connections on this port right now."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.settimeout(0.2)
        return sock.connect_ex((host, port)) == 0


def loopback_router(port: int | None = None) -> ZenohSettings:
    """An embedded router listening on 127.0.0.1 (a free port unless one is given)."""
    return ZenohSettings(mode="router", listen=[f"tcp/127.0.0.1:{port or free_port()}"])


def client_of(router: ZenohSettings) -> ZenohSettings:
    """Settings for a client of the given router."""
    return ZenohSettings(mode="client", connect=list(router.listen))


def _config_file(path: str) -> zenoh.Config:
    """A --zenoh-config file as zenoh reads it; a TransportError naming the file if it cannot be read."""
    try:
        return zenoh.Config.from_file(path)
    except Exception as err:  # zenoh's ZError, its text multi-line
        text = _plain(str(err))
        os_error = _OS_ERROR.search(text)
        said = re.search(r'msg: "(.+?)"|= (.+)$', text)  # the JSON5 parser's or the configuration's complaint
        complaint = f": {_shortened(said.group(1) or said.group(2))}" if said else ""
        reason = os_error.group(1).strip().lower() if os_error else f"not a zenoh JSON5 configuration{complaint}"
        raise TransportError(f"--zenoh-config {path}: {reason}") from None


def _shortened(text: str, most: int = 100) -> str:
    """At most ``most`` characters, cut after a whole clause (zenoh's may list every field it knows)."""
    cut = text.rfind(",", 0, most)
    return text if len(text) <= most else f"{text[: cut if cut > 0 else most]}, ..."


def listen_endpoints(settings: ZenohSettings) -> list[str]:
    """Where a session listens: its flags', else its configuration file's (TransportError: a file that cannot be read)."""
    if settings.listen or not settings.config_file:
        return list(settings.listen)
    return _configured(_config_file(settings.config_file), "listen/endpoints", settings.mode)


def _endpoints(settings: ZenohSettings, conf: zenoh.Config | None) -> list[str]:
    """Where a session listens (or connects, if it does not listen): its flags', else its configuration file's."""
    ours = settings.listen or settings.connect
    if ours or conf is None:
        return ours
    return _configured(conf, "listen/endpoints", settings.mode) or _configured(conf, "connect/endpoints", settings.mode)


def _configured(conf: zenoh.Config, key: str, mode: str) -> list[str]:
    """A configuration's endpoints under ``key`` for a session of ``mode``."""
    endpoints = json.loads(conf.get_json(key))
    if isinstance(endpoints, dict):  # zenoh's per-mode default
        endpoints = endpoints.get(mode, [])
    return [str(e) for e in endpoints]


def open_session(settings: ZenohSettings) -> zenoh.Session:
    """Open a session; any failure becomes a TransportError with a one-line reason."""
    conf = None
    try:
        conf = settings.to_config()
        return zenoh.open(conf)
    except TransportError:  # said already (a bad mode, a configuration file that cannot be read)
        raise
    except Exception as err:  # zenoh raises ZError with multi-line text
        endpoints = _endpoints(settings, conf)
        where = ", ".join(endpoints) or "(no endpoint)"
        reason, hint = zenoh_reason(str(err) or type(err).__name__, settings.mode, endpoints)
        raise TransportError(f"cannot open zenoh {settings.mode} session on {where}: {reason}; {hint}") from None


# zenoh's errors end each cause with the Rust source it came from: "... at /root/.cargo/git/.../tcp.rs:61."
_SOURCE = re.compile(r"\s+at\s+\S+\.rs:\d+\.?")
_OS_ERROR = re.compile(r"([^\[\]:]+?) \(os error \d+\)")  # the innermost cause: "Address already in use (os error 98)"
_ENDPOINT_FORM = "an endpoint reads PROTOCOL/HOST:PORT, e.g. tcp/127.0.0.1:7447"
_NO_ROUTER = "is a router running there? start one with `pixelswarm router`"
_HINTS = (  # (what zenoh's text says, lower case; the hint for the user: {listen} the endpoint with another port)
    ("address already in use", "another process holds that port: choose another with -l {listen}"),
    ("cannot assign requested address", "no network interface of this machine has that address"),
    ("permission denied", "ports below 1024 need privileges: choose a port above"),
    ("invalid", _ENDPOINT_FORM),
    ("must be of the form", _ENDPOINT_FORM),
    ("not supported", "use a protocol zenoh speaks, e.g. tcp/127.0.0.1:7447"),
    ("unable to connect", _NO_ROUTER),
)


def zenoh_reason(text: str, mode: str, endpoints: list[str] | None = None) -> tuple[str, str]:
    """zenoh's error text as (the reason in a few words, a hint for the user): without the Rust
    source paths it carries, the innermost operating-system error if there is one. A hint to listen
    elsewhere keeps the protocol and host of the endpoint the text names (a tls one stays tls)."""
    text = _plain(text)
    lower = text.lower()
    os_error = _OS_ERROR.search(text)
    if os_error:
        reason = os_error.group(1).strip()
    elif "must be of the form" in lower:  # the endpoint did not parse: zenoh's text repeats the form
        reason = "not an endpoint"
    elif "unable to connect" in lower:
        reason = "nothing answered" + (" in time" if "timeout" in lower else "")
    else:
        reason = text.strip(" .")
    default = "is the port already in use? choose another with -l {listen}" if mode == "router" else _NO_ROUTER
    hint = next((h for pattern, h in _HINTS if pattern in lower), default)
    tls = any(e.startswith("tls/") for e in endpoints or [])
    refused = any(w in lower for w in ("certificate", "trust anchor", "private key", "tls listener"))
    refused_or_silent = refused or (mode != "router" and "unable to connect" in lower)
    if tls and refused_or_silent and "address already in use" not in lower:
        # over TLS a refused certificate (expired, another authority's, damaged) looks like silence
        hint = "are the certificates of one folder, readable and not expired?"
        hint = hint if mode == "router" else f"is a router running there, and {hint}"
    return reason[:1].lower() + reason[1:], hint.format(listen=_another_port(text, endpoints or []))


def _plain(text: str) -> str:
    """zenoh's error text on one line, without the Rust source paths it carries."""
    return " ".join(_SOURCE.sub("", text).split())


def _another_port(text: str, endpoints: list[str]) -> str:
    """The endpoint zenoh's text names (else the first), its port as PORT: tls/127.0.0.1:PORT."""
    named: list[str] = []
    others: list[str] = []
    for endpoint in endpoints:
        locator = endpoint.split("#")[0].split("?")[0]  # without zenoh's metadata and configuration
        proto, slash, address = locator.partition("/")
        host, colon, _ = address.rpartition(":")
        if slash and colon:
            (named if address in text else others).append(f"{proto}/{host}:PORT")
    return next(iter(named + others), "tcp/127.0.0.1:PORT")


def one_malloc_arena() -> bool:
    """Have every thread of this process share one malloc arena (glibc's per-thread arenas' part-used pages
    count in RSS), for a robot's process, which allocates little; False without glibc's mallopt."""
    import ctypes  # here, not above: numpy loads it anyway, a process without numpy only if it asks

    m_arena_max = -8  # glibc's malloc.h
    try:
        return bool(ctypes.CDLL(None).mallopt(m_arena_max, 1))
    except (AttributeError, OSError, TypeError):
        return False


# The zenoh flags' help, for argparse (add_zenoh_args) and for a robot's process, which parses with getopt
# (ZENOH_SHORT, ZENOH_LONG, zenoh_usage) as argparse would stay in its memory.
ZENOH_HELP = {
    "--mode": "session mode (default {default_mode})",
    "--connect": "endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)",
    "--listen": "endpoint to listen on, e.g. tcp/127.0.0.1:7447 (repeatable)",
    "--no-multicast-scouting": "disable multicast scouting (the default)",
    "--multicast-scouting": "enable multicast scouting (finds peers on the LAN)",
    "--zenoh-config": "zenoh JSON5 configuration to start from, e.g. a role's file from `pixelswarm certs` "
    "(the flags override it)",
}
ZENOH_SHORT = "m:e:l:"
ZENOH_LONG = ["mode=", "connect=", "listen=", "multicast-scouting", "no-multicast-scouting", "zenoh-config="]
_ZENOH_SHOWN = {  # how the help shows a flag with a short form or an argument
    "--mode": "-m, --mode {" + ",".join(MODES) + "}",
    "--connect": "-e, --connect ENDPOINT",
    "--listen": "-l, --listen ENDPOINT",
    "--zenoh-config": "--zenoh-config FILE",
}


def add_zenoh_args(parser: argparse.ArgumentParser, default_mode: str = "client") -> None:
    """Zenoh-style flags: -m/--mode, -e/--connect, -l/--listen, --no-multicast-scouting."""
    group = parser.add_argument_group("zenoh")
    mode_help = ZENOH_HELP["--mode"].format(default_mode=default_mode)
    group.add_argument("-m", "--mode", choices=MODES, default=default_mode, help=mode_help)
    group.add_argument("-e", "--connect", action="append", default=[], metavar="ENDPOINT", help=ZENOH_HELP["--connect"])
    group.add_argument("-l", "--listen", action="append", default=[], metavar="ENDPOINT", help=ZENOH_HELP["--listen"])
    for flag, action in (("--no-multicast-scouting", "store_false"), ("--multicast-scouting", "store_true")):
        group.add_argument(flag, dest="multicast_scouting", action=action, default=False, help=ZENOH_HELP[flag])
    group.add_argument("--zenoh-config", metavar="FILE", help=ZENOH_HELP["--zenoh-config"])


def zenoh_usage() -> str:
    """The zenoh flags' part of a help text, laid out as argparse lays out add_zenoh_args's."""
    lines = ["zenoh:"]
    for flag, shown in ((flag, _ZENOH_SHOWN.get(flag, flag)) for flag in ZENOH_HELP):
        text = textwrap.fill(ZENOH_HELP[flag].format(default_mode="client"), 76, subsequent_indent=" " * 24)
        lines.append(f"  {shown:<22}{text}" if len(shown) < 21 else f"  {shown}\n{'':24}{text}")
    return "\n".join(lines)


def settings_from_options(options: list[tuple[str, str]]) -> ZenohSettings:
    """The settings of the zenoh flags among getopt's (flag, value) pairs; other flags are the caller's."""
    settings = ZenohSettings()
    for flag, value in options:
        if flag in ("-m", "--mode"):
            settings.mode = value
        elif flag in ("-e", "--connect"):
            settings.connect.append(value)
        elif flag in ("-l", "--listen"):
            settings.listen.append(value)
        elif flag in ("--multicast-scouting", "--no-multicast-scouting"):
            settings.multicast_scouting = flag == "--multicast-scouting"
        elif flag == "--zenoh-config":
            settings.config_file = value
    return settings


def settings_from_args(args: argparse.Namespace) -> ZenohSettings:
    """The settings of add_zenoh_args's flags."""
    connect, listen = list(args.connect), list(args.listen)
    return ZenohSettings(args.mode, connect, listen, args.multicast_scouting, config_file=args.zenoh_config)
