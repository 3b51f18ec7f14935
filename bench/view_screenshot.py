"""`pixelswarm run --view web` in a browser: a headless Chromium opens the printed address and takes a
screenshot of the robots (issue 44; docs/view_1000.png is one, at the L of the 1000-robot sequence).

    .venv/bin/python -m bench.view_screenshot [--scene paper-sequence-1000] [--duration 300] \\
        [--out docs/view_1000.png]

It runs `pixelswarm run SCENE --engine central --view web --duration D` (the L is the shown picture from
240 s to 300 s), waits for the run's directory on stdout (the web viewer then holds the whole run and
keeps serving), opens the address in headless Chromium, waits until the display shows the robots and
stops changing, saves the screenshot and stops the run with SIGINT.

Needs Chromium (Debian's package `chromium`: /usr/bin/chromium) and Playwright (`pip install playwright`;
its own browser download is not needed: it drives the system's Chromium). The browser reaches 127.0.0.1
only: every other request (Rerun's web viewer asks for its examples and sends usage statistics) is
aborted. Rendering is in software (SwiftShader), as on a machine without a GPU.
"""

from __future__ import annotations

import argparse
import io
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import urllib.parse
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .common import REPO

# Chromium as root in a container without a GPU: no sandbox, WebGL through SwiftShader, and none of its
# own calls home (this machine's network refuses them, many at a time)
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-quic",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--ignore-gpu-blocklist",
]
VIEWPORT = {"width": 1280, "height": 800}
PAGE_TIMEOUT = 180.0  # s for the viewer's page to show the robots (software rendering of a wasm app)
RUN_TIMEOUT = 900.0  # s for the run to end


def chromium() -> str | None:
    """The system's Chromium, if installed."""
    return shutil.which("chromium") or shutil.which("chromium-browser")


def loopback(url: str) -> bool:
    return urllib.parse.urlparse(url).hostname in ("127.0.0.1", "localhost")


def decode_png(data: bytes) -> np.ndarray:
    """A screenshot as an (H, W, 3) RGB array."""
    import cv2

    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    return image[..., ::-1].copy()


def screenshot(url: str, ready: Callable[[np.ndarray], bool], path: Path | None = None) -> np.ndarray:
    """Open ``url`` in headless Chromium, wait until ``ready(screenshot)`` holds and the picture stops
    changing (at most PAGE_TIMEOUT), and return the screenshot (also written to ``path``). TimeoutError
    if it never does."""
    from playwright.sync_api import sync_playwright

    executable = chromium()
    if executable is None:
        raise FileNotFoundError("no Chromium installed (Debian: apt-get install chromium)")
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=executable, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport=VIEWPORT)
            page.route("**/*", lambda route: route.continue_() if loopback(route.request.url) else route.abort())
            page.goto(url)
            return _settle(page, ready, path)
        finally:
            browser.close()


def _settle(page: Any, ready: Callable[[np.ndarray], bool], path: Path | None) -> np.ndarray:
    end = time.monotonic() + PAGE_TIMEOUT
    last: np.ndarray | None = None
    while time.monotonic() < end:
        time.sleep(2.0)
        data = page.screenshot()
        image = decode_png(data)
        if ready(image) and last is not None and np.abs(image.astype(int) - last).mean() < 0.5:
            if path is not None:
                path.write_bytes(data)
            return image
        last = image.astype(int)
    if path is not None:  # what the page showed instead, beside the screenshot it should have been
        path.with_name(path.stem + "-timeout.png").write_bytes(data)
    raise TimeoutError(f"the page at {page.url} did not show the robots within {PAGE_TIMEOUT:g} s")


def coloured(image: np.ndarray) -> np.ndarray:
    """Where the screenshot is saturated colour (robots in their LEDs), not Rerun's greys and whites."""
    rgb = image.astype(int)
    return (rgb.max(axis=2) - rgb.min(axis=2)) > 80


def _read_lines(stream: io.TextIOBase, into: list[str]) -> None:
    for line in stream:
        into.append(line)


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scene", default="paper-sequence-1000")
    parser.add_argument("--duration", type=float, default=300.0)
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "view_1000.png")
    args = parser.parse_args()
    if chromium() is None:
        print("view_screenshot: no Chromium installed (Debian: apt-get install chromium)", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        command = [sys.executable, "-m", "sim.cli", "run", args.scene, "--engine", "central", "--view", "web"]
        command += ["--duration", f"{args.duration:g}", "--no-video", "--no-plots", "--out", f"{tmp}/run"]
        run = subprocess.Popen(command, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        out: list[str] = []
        err: list[str] = []
        readers = [
            threading.Thread(target=_read_lines, args=(s, into), daemon=True)
            for s, into in ((run.stdout, out), (run.stderr, err))
        ]
        for reader in readers:
            reader.start()
        try:
            end = time.monotonic() + RUN_TIMEOUT
            while not out and run.poll() is None and time.monotonic() < end:
                time.sleep(0.5)  # the run directory on stdout: the run has ended, the viewer holds it all
            url = next((line.split("view: ", 1)[1].split()[0] for line in err if "view: http" in line), None)
            if not out or url is None:
                print(
                    f"view_screenshot: the run did not end with a view address: {''.join(err)[-2000:]}", file=sys.stderr
                )
                return 1
            screenshot(url, lambda image: coloured(image).mean() > 0.01, args.out)
        finally:
            if run.poll() is None:
                run.send_signal(signal.SIGINT)  # the view serves until Ctrl-C
                try:
                    run.wait(60)
                except subprocess.TimeoutExpired:
                    run.kill()
                    run.wait()
    print(args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
