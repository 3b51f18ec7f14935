"""docs/cli.md says everything `pixelswarm --help` says: every flag of every sub-command is named under
that command's heading, so that the reference and the parser cannot drift apart."""

from __future__ import annotations

import argparse
import re

from sim.cli.main import build_parser
from tests.conftest import REPO

CLI_MD = REPO / "docs" / "cli.md"


def subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    (sub,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def sections(text: str) -> dict[str, str]:
    """Each `## pixelswarm NAME ...` section of the page, its `###` subsections included, by NAME."""
    found: dict[str, str] = {}
    for part in re.split(r"(?m)^(?=## )", text):
        heading = re.match(r"## pixelswarm ([\w-]+)", part)
        if heading:
            found[heading.group(1)] = found.get(heading.group(1), "") + part
    return found


def undocumented(parser: argparse.ArgumentParser, section: str) -> list[str]:
    """The option strings of the parser that the section never names (as a whole word: `--connect`
    is not found in `--agents-connect`)."""
    options = [o for a in parser._actions if not isinstance(a, argparse._HelpAction) for o in a.option_strings]
    return [o for o in options if not re.search(rf"(?<![\w-]){re.escape(o)}(?![\w-])", section)]


def test_the_check_finds_an_undocumented_flag():
    parser = argparse.ArgumentParser()
    parser.add_argument("-e", "--connect")
    parser.add_argument("--zenoh-config")
    assert undocumented(parser, "| `-e/--connect` | ... `--agents-connect`, `--zenoh-config-file` |") == [
        "--zenoh-config"
    ]


def test_every_subcommand_has_a_section():
    assert sorted(set(subcommands()) - set(sections(CLI_MD.read_text()))) == []


def test_every_flag_of_every_subcommand_is_in_its_section():
    text = sections(CLI_MD.read_text())
    missing = {name: gaps for name, p in subcommands().items() if (gaps := undocumented(p, text.get(name, "")))}
    assert missing == {}, f"docs/cli.md does not name these flags under their command's heading: {missing}"
