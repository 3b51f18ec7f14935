"""Transport mistakes at the command line as a user makes them: a fault plan's setting left without its
value or misnamed, and a --zenoh-config file that is not there. One line that says what is wrong (not a
busy port, not an unknown setting that exists), exit 2, no traceback, nothing written."""

from __future__ import annotations

import pytest

from tests.conftest import run_pixelswarm


def refused(*args: str) -> str:
    result = run_pixelswarm(*args, timeout=120)
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
    return lines[0]


@pytest.mark.parametrize(
    "plan, said",
    [
        ("state:drop", "fault 'state:drop': drop needs a value, e.g. state:drop=0.1"),
        ("state:loss=0.2", "fault 'state:loss=0.2': no setting 'loss' (did you mean 'drop'? settings: drop, delay"),
    ],
)
def test_a_fault_plan_setting_without_a_value_or_misnamed_is_said_with_the_settings(tmp_path, plan, said):
    out = tmp_path / "r"
    line = refused("run", "circle", "--faults", plan, "--out", str(out), "--no-video", "--no-plots", "-q")
    assert line.startswith(f"pixelswarm run: error: --faults: {said}"), line
    assert "a plan reads KIND:drop=P,delay=S,jitter=S" in line
    assert not list(tmp_path.iterdir())


def test_a_missing_zenoh_config_file_is_said_as_missing_not_as_a_busy_port(tmp_path):
    missing = tmp_path / "router.json5"
    line = refused("router", "--zenoh-config", str(missing))
    assert line == f"pixelswarm router: error: --zenoh-config {missing}: no such file or directory"


@pytest.mark.parametrize(
    "text, mode, hint",
    [
        ("Unable to connect to any of [tls/127.0.0.1:5]! timeout", "client", "is a router running there, and are the"),
        ("Cannot create a new TLS listener: no root trust anchors were provided", "router", "are the certificates of"),
        ("Invalid TLS private key file: No such file or directory (os error 2)", "client", "readable and not expired"),
        (
            "TLS listener on tls/127.0.0.1:5: Address already in use (os error 98)",
            "router",
            "choose another with -l tls",
        ),
    ],
)
def test_over_tls_a_refused_certificate_is_hinted_as_such(text, mode, hint):
    """A session with a wrong, expired or missing certificate was told to start a router, or that its
    port was busy, or how an endpoint is written: over TLS the certificates are what to check."""
    from transport.session import zenoh_reason

    assert hint in zenoh_reason(text, mode, ["tls/127.0.0.1:5"])[1]
