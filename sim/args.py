"""Argument types shared by the command line's subcommands, and robot ids as users and messages write them."""

from __future__ import annotations

import argparse
import itertools
import math
import sys
import typing
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from transport.codec import MAX_ROBOTS

STARTUP_TIMEOUT = 300.0  # s per start-up stage of a run: generous, many processes start at once
AGENTS_TIMEOUT = 60.0  # s a run with remote agents waits for every robot's agent to come alive by default
ENDPOINT_FORM = "expected PROTOCOL/ADDRESS, e.g. tcp/127.0.0.1:7447"


class UsageError(Exception):
    """Bad input from the user: one line `PROG: error: ...` (refuse), exit code 2."""


class OneLineParser(argparse.ArgumentParser):
    """Usage errors as one line (and exit code 2), with `--help` for the rest."""

    def error(self, message: str) -> typing.NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def refuse(prog: str, message: object) -> int:
    """A command's bad input as one line `PROG: error: ...` on stderr; returns its exit code, 2."""
    print(f"{prog}: error: {message}", file=sys.stderr)
    return 2


@contextmanager
def usage_errors(*kinds: type[Exception], prefix: str = "") -> Iterator[None]:
    """Exceptions of ``kinds`` raised inside as a UsageError (``prefix`` and their text): the input's fault."""
    try:
        yield
    except kinds as err:
        raise UsageError(f"{prefix}{err}") from None


def refuse_if(when: object, message: str) -> None:
    """UsageError(message) if ``when`` holds: input the command cannot honour."""
    if when:
        raise UsageError(message)


def positive_int(text: str) -> int:
    """A whole number of at least 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, not {value}")
    return value


def robot_count(text: str) -> int:
    """A number of robots: a whole number from 1 to MAX_ROBOTS."""
    value = positive_int(text)
    if value > MAX_ROBOTS:
        raise argparse.ArgumentTypeError(f"at most {MAX_ROBOTS} robots (robot ids are 16-bit on the bus), not {value}")
    return value


def display_name(text: str) -> str:
    """A display name (the key prefix px/<name>/...), as transport.keys.Keys takes one."""
    from transport.keys import Keys  # here, as zenoh below: the emulators import this module and need neither

    try:
        Keys(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None
    return text


def zenoh_endpoint(text: str) -> str:
    """A zenoh endpoint, as zenoh itself reads one (PROTOCOL/ADDRESS)."""
    from transport.session import ZenohSettings

    try:
        ZenohSettings(mode="client", connect=[text]).to_config()  # zenoh's own check of the endpoint's form
    except Exception:
        raise argparse.ArgumentTypeError(f"{text!r} is not an endpoint: {ENDPOINT_FORM}") from None
    return text


def new_directory(text: str) -> Path:
    """A directory to make: not '', '.', '/' nor a path ending in '..', which name one there already is."""
    path = Path(text)
    if not text.strip() or path.name in ("", ".."):
        raise argparse.ArgumentTypeError(f"{text!r} names no new directory: give one to make, e.g. runs/mine")
    return path


def positive_number(text: str) -> float:
    """A finite number above 0."""
    return _positive(text, "number")


def positive_seconds(text: str) -> float:
    """A finite number of seconds above 0."""
    return _positive(text, "number of seconds")


def _positive(text: str, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a {what}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive {what}, not {text}")
    return value


def add_seconds(parser: argparse.ArgumentParser, flag: str, default: float, help: str) -> None:
    """A flag for how long to wait, in seconds above 0, whose help ends with its default."""
    parser.add_argument(
        flag, type=positive_seconds, default=default, metavar="SECONDS", help=f"{help} (default {default:g} s)"
    )


def check_endpoint(settings: typing.Any, endpoint: str) -> None:
    """UsageError unless zenoh reads ``endpoint``, which ``settings`` connect to, as an endpoint."""
    try:
        settings.to_config()  # zenoh's own check of the endpoint's form
    except Exception:
        raise UsageError(f"--connect {endpoint!r} is not an endpoint: {ENDPOINT_FORM}") from None


def parse_ids(text: str) -> list[int]:
    """Robot ids as a user writes them: '0-3,7' -> [0, 1, 2, 3, 7]."""
    ids: set[int] = set()
    for part in text.split(","):
        low, dash, high = part.strip().partition("-")
        if not low.isdigit() or (dash and not high.isdigit()):
            raise ValueError(f"--robots {text!r}: expected ids and ranges like 0-3,7")
        first, last = int(low), int(high) if dash else int(low)
        if last < first:
            raise ValueError(f"--robots {text!r}: the range {part.strip()} runs backwards")
        ids.update(range(first, last + 1))
    return sorted(ids)


def format_ids(ids: list[int]) -> str:
    """The reverse of parse_ids, for messages: [0, 1, 2, 3, 7] -> '0-3, 7'."""
    runs = [[i for _, i in run] for _, run in itertools.groupby(enumerate(sorted(ids)), lambda k_i: k_i[1] - k_i[0])]
    return ", ".join(str(r[0]) if len(r) == 1 else f"{r[0]}-{r[-1]}" for r in runs)
