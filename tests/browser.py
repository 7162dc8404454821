"""Headless Chromium for the tests of ``stableins serve``: Debian's chromium and chromium-driver through Selenium.

The browser comes from Debian's packages (``make system-deps``): a test tool that downloads a browser of its own
cannot work on machines without the network.  Chromium starts headless with the flags that keep it off the network
(no background networking, component updates or sync) and a fresh profile; downloads go to a folder of the test's.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"
FLAGS = (
    "--headless=new",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-dev-shm-usage",
    "--window-size=1400,1000",
)


def missing_reason() -> str | None:
    """Why the browser tests cannot run here (None when they can)."""
    for path in (CHROMIUM, CHROMEDRIVER):
        if not os.access(path, os.X_OK):
            return f"{path} is not installed: `make system-deps` installs Debian's chromium and chromium-driver"
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed: pip install -e '.[test]'"
    try:
        import fastapi  # noqa: F401
        import uvicorn  # noqa: F401
    except ImportError:
        return "FastAPI and uvicorn are not installed: pip install -e '.[test]'"
    return None


def browser(downloads: Path):
    """Start headless Chromium (through chromedriver) saving downloads in ``downloads``; the caller quits it."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    profile = tempfile.mkdtemp(prefix="stableins-chromium-")
    for flag in (*FLAGS, f"--user-data-dir={profile}"):
        options.add_argument(flag)
    options.add_experimental_option(
        "prefs",
        {"download.default_directory": str(downloads), "download.prompt_for_download": False, "safebrowsing.enabled": False},
    )
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    driver.set_page_load_timeout(30)
    driver.profile_directory = profile  # removed by quit()
    return driver


def quit_browser(driver) -> None:
    """Quit the browser and remove its profile."""
    try:
        driver.quit()
    finally:
        shutil.rmtree(driver.profile_directory, ignore_errors=True)


class Server:
    """``stableins serve`` in a process of its own, on a free port of 127.0.0.1."""

    def __init__(self, *arguments: str, env: dict[str, str] | None = None) -> None:
        argv = [sys.executable, "-m", "stableins.cli", "serve", "--port", "0", *arguments]
        self.process = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        assert self.process.stdout is not None
        line = self.process.stdout.readline()
        match = re.match(r"serving on (http://\S+)", line)
        if match is None:
            self.process.kill()
            raise AssertionError(f"stableins serve did not start: {line!r} {self.process.stderr.read() if self.process.stderr else ''}")
        self.url = match.group(1)

    def stop(self) -> None:
        """Stop the server (SIGTERM, then SIGKILL)."""
        self.process.terminate()
        try:
            self.process.wait(10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait(10)
        for stream in (self.process.stdout, self.process.stderr):
            if stream is not None:
                stream.close()


def wait_for(condition, timeout: float = 20.0, interval: float = 0.05):
    """Return the first true value of ``condition()`` within ``timeout`` seconds (AssertionError otherwise)."""
    end = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > end:
            raise AssertionError(f"not within {timeout} s: {condition}")
        time.sleep(interval)
