"""`pixelswarm certs DIR --robots N`: certificates, configurations and access rules for a secured bus
(transport/security.py, docs/security.md)."""

from __future__ import annotations

import argparse
from typing import Any

from sim.args import UsageError, positive_int
from transport.security import SecurityError, make_certificates

# `pixelswarm --help` and `pixelswarm certs --help`
HELP = "make certificates, client configurations and access rules for a secured bus"
ABOUT = (
    "Make a certificate authority, a certificate and a Zenoh configuration for each role "
    "(coordinator, tracker, world, recorder, observer, router, robot-<id>), and the router's access rules."
)


def add_certs_parser(subparsers: Any) -> None:
    """Add the `certs` subcommand to an argparse subparsers object (sets func=run_certs)."""
    p = subparsers.add_parser("certs", help=HELP, description=ABOUT)
    p.add_argument("dir", help="folder to create (must not exist or be empty)")
    p.add_argument("-n", "--robots", type=positive_int, required=True, help="number of robots (ids 0..N-1)")
    p.add_argument(
        "--listen",
        metavar="tls/HOST:PORT",
        help="the router's endpoint, written into every configuration and named by the router "
        "certificate (default: none written; give it when a session opens)",
    )
    p.add_argument("--display", default="default", help="display name (key prefix) the access rules cover")
    p.add_argument("--force", action="store_true", help="replace an existing non-empty folder")
    p.set_defaults(func=run_certs)


def run_certs(args: argparse.Namespace) -> int:
    """The command; bad input is a UsageError, which `pixelswarm` says as one line (exit code 2)."""
    try:
        path = make_certificates(args.dir, args.robots, connect=args.listen, display=args.display, overwrite=args.force)
    except (SecurityError, ValueError) as err:
        raise UsageError(str(err)) from None
    except OSError as err:
        raise UsageError(f"cannot write {args.dir}: {err.strerror or err}") from None
    print(path)
    return 0
