"""`pixelswarm run --secure DIR`: what a secured run refuses before anything starts, each in one line.

A secured run itself, with a rogue robot's and the observer's forged goal sets dropped at its router, is
test_view_connect.py's (a viewer watches it as the observer).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from sim.cli.main import main
from tests.conftest import run_pixelswarm
from transport.security import check_folder, make_certificates
from transport.session import free_port


@pytest.fixture(scope="module")
def two_robots(tmp_path_factory) -> Path:
    return make_certificates(tmp_path_factory.mktemp("secure") / "certs", 2)


BAD_INPUTS = [
    (["--secure", "{tmp}/missing"], "is not a folder"),
    (["--secure", "{tmp}/empty"], "roles.json missing"),
    (["--secure", "{certs}"], "made for 2 robots and this run has 3"),
    (["--secure", "{certs}", "--robots", "2", "-k", "2"], "one robot per agent process"),
    (["--secure", "{certs}", "--robots", "2", "-e", "tls/127.0.0.1:{port}"], "cannot be used with -e"),
    (["--secure", "{certs}", "--robots", "2", "--agents-connect", "tls/127.0.0.1:{port}"], "--agents-connect"),
    (["--secure", "{certs}", "--robots", "2", "--listen", "tcp/127.0.0.1:{port}"], "TLS only"),
    (["--secure", "{certs}", "--robots", "2", "--display", "other"], "display 'default', not 'other'"),
    (["--secure", "{certs}", "--robots", "2", "--engine", "central"], "central engine has none"),
    (["--secure", "{certs}", "--robots", "2", "--zenoh-config", "{certs}/world.json5"], "--zenoh-config"),
]


@pytest.mark.parametrize("extra, message", BAD_INPUTS)
def test_bad_input_to_a_secured_run_is_one_line_and_exit_2(extra, message, two_robots, tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    fill = {"tmp": str(tmp_path), "certs": str(two_robots), "port": str(free_port())}
    out = tmp_path / "run"
    code = main(
        [
            "run",
            "swap",
            "--robots",
            "3",
            "--no-video",
            "--no-plots",
            "--out",
            str(out),
            *[a.format(**fill) for a in extra],
        ]
    )
    err = capsys.readouterr().err
    assert code == 2 and message in err, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not out.exists() and not out.with_name("run.partial").exists()


def test_a_folder_missing_a_robots_key_is_refused_before_anything_starts(tmp_path):
    folder = make_certificates(tmp_path / "certs", 2)
    key = folder / "robot-1-key.pem"
    key.unlink()
    out = tmp_path / "run"
    result = run_pixelswarm("run", "swap", "--robots", "2", "--secure", str(folder), "--out", str(out), timeout=60)
    assert result.returncode == 2, result.stderr
    assert f"cannot read {key}" in result.stderr and len(result.stderr.strip().splitlines()) == 1
    assert "Traceback" not in result.stderr and result.stdout == ""
    assert not out.exists() and not out.with_name("run.partial").exists()


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads every file")
def test_an_unreadable_folder_is_refused(tmp_path):
    folder = make_certificates(tmp_path / "certs", 2)
    folder.chmod(0)
    try:
        with pytest.raises(ValueError, match="cannot read"):
            check_folder(folder, 2)
    finally:
        folder.chmod(0o700)


@pytest.mark.slow
def test_a_world_that_cannot_join_is_said_in_its_own_words_and_nothing_is_written(tmp_path):
    """The world's certificate damaged: it dies at start-up. That was blamed on the agents (exit 3, 'no
    agent came alive before the world process ended'), and start-up failures pointed at a log inside the
    run directory they had just removed. Exit 1, the world's own last line, nothing written."""
    certs = make_certificates(tmp_path / "certs", 2)  # its files named by absolute path: damaged where made
    (certs / "world.pem").write_text("not a certificate\n")
    out = tmp_path / "r"
    result = run_pixelswarm(
        "run", "circle", "--robots", "2", "--secure", str(certs), "--out", str(out), "--no-video", "--no-plots",
        "--startup-timeout", "30", timeout=180,
    )  # fmt: skip
    assert result.returncode == 1, result.stderr
    line = result.stderr.strip().splitlines()[-1]
    assert line.startswith("pixelswarm run: error: the world process exited with code "), line
    assert "see " not in line and not out.exists() and not out.with_name("r.partial").exists()
