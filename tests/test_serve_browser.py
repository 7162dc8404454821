"""``stableins serve`` in a real browser (issue 32): headless Chromium through fleet → unit → certificate → runs.

The store and the run root are made by the toolkit's own commands (``stableins run`` on the simulated platform,
``stableins history --add``); the server runs as a user starts it (``stableins serve``, a process of its own); the
browser is Debian's Chromium driven by Selenium.  Each page is saved as a screenshot, in the test's folder or, with
``STABLEINS_SCREENSHOTS=docs/img``, where docs/fleet.md shows them (``fleet.png``, ``unit.png``, ``runs.png``,
``runs-live.png``).  Skipped, with the reason, only where Chromium, chromedriver or Selenium are missing
(``make system-deps`` installs them).
"""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from browser import Server, browser, missing_reason, quit_browser, wait_for

from stableins import cli

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.skipif(missing_reason() is not None, reason=missing_reason() or "")


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """A run root with three runs of ``device-coarse`` (two of SN-A, one of SN-B), each filed in a history store."""
    from test_docs_commands import _fast, _fast_draw, _person

    import stableins.procedures.definition
    from stableins.console import Console
    from stableins.simulator.truth import Truth

    root = tmp_path_factory.mktemp("lab")
    with pytest.MonkeyPatch.context() as mp:  # the documentation test's fast settings: 2 Hz
        mp.setattr(Truth, "draw", _fast_draw(Truth.draw.__func__))
        mp.setattr(stableins.procedures.definition, "load_procedure", _fast(stableins.procedures.definition.load_procedure))
        mp.setattr(Console, "_ask", _person)
        mp.setattr("os.fsync", lambda fd: None)
        mp.setenv("MPLBACKEND", "Agg")
        for unit, seed, name in (("SN-A", "1", "a1"), ("SN-B", "3", "b1"), ("SN-A", "2", "a2")):
            out = root / "runs" / name
            assert cli.main(["run", "device-coarse", "--driver", "sim", "--unit", unit, "--seed", seed, "--out", str(out)]) == 0
            assert cli.main(["history", unit, "--store", str(root / "store"), "--add", str(out / "record.json")]) == 0
    # the laboratory's policy: SN-B is checked every second (so it is overdue when the page opens), the rest yearly
    (root / "policy.toml").write_text("[interval]\ndefault = 365\n\n[interval.unit]\nSN-B = 0.00001\n", encoding="utf-8")
    return root


@pytest.fixture()
def images(tmp_path) -> Path:
    """Where the screenshots go: ``$STABLEINS_SCREENSHOTS`` (docs/img for the documentation), else the test's folder."""
    folder = Path(os.environ.get("STABLEINS_SCREENSHOTS") or tmp_path / "screenshots")
    folder.mkdir(parents=True, exist_ok=True)
    return folder


@pytest.fixture()
def chromium(tmp_path):
    driver = browser(tmp_path / "downloads")
    yield driver
    quit_browser(driver)


@pytest.mark.slow  # three runs of device-coarse make the store and the run root (about 15 s of CPU), then the pages
def test_fleet_unit_certificate_and_runs_in_chromium(lab, chromium, images, tmp_path):
    from selenium.webdriver.common.by import By

    server = Server("--store", str(lab / "store"), "--runs", str(lab / "runs"), "--policy", str(lab / "policy.toml"))
    try:
        time.sleep(0.05)  # SN-B's one-second interval runs out
        # fleet: the overdue unit first, with its due date and the conformity its certificate states
        chromium.get(f"{server.url}/fleet")
        rows = chromium.find_elements(By.CSS_SELECTOR, "#fleet tbody tr")
        assert [r.get_attribute("data-serial") for r in rows] == ["SN-B", "SN-A"]
        assert "overdue" in rows[0].get_attribute("class") and "overdue by" in rows[0].text
        assert "PASS" in rows[0].text and "PASS" in rows[1].text
        chromium.save_screenshot(str(images / "fleet.png"))
        # search
        box = chromium.find_element(By.ID, "search")
        box.send_keys("SN-A")
        box.submit()
        wait_for(lambda: len(chromium.find_elements(By.CSS_SELECTOR, "#fleet tbody tr")) == 1)
        # unit: the history, the trend plots drawn by Plotly
        chromium.find_element(By.LINK_TEXT, "SN-A").click()
        wait_for(lambda: chromium.find_elements(By.CSS_SELECTOR, ".trend .plot[data-drawn='true'] svg.main-svg"))
        plots = chromium.find_elements(By.CSS_SELECTOR, ".trend .plot[data-drawn='true']")
        assert len(plots) >= 15  # every parameter the two coarse calibrations determine from their own data
        assert len(chromium.find_elements(By.CSS_SELECTOR, "#history tbody tr")) == 2
        chromium.save_screenshot(str(images / "unit.png"))
        # the certificate of the record in force, downloaded, with the SHA-256 of the file the run wrote
        link = chromium.find_elements(By.CSS_SELECTOR, "#history tbody tr.in-force a.document.certificate")[0]
        expected = hashlib.sha256((lab / "runs" / "a2" / "report.pdf").read_bytes()).hexdigest()
        assert link.get_attribute("data-sha256") == expected
        link.click()
        saved = wait_for(lambda: [p for p in (tmp_path / "downloads").glob("*.pdf")], timeout=30)
        wait_for(lambda: hashlib.sha256(saved[0].read_bytes()).hexdigest() == expected, timeout=10)
        # runs: every run under the run root, finished
        chromium.find_element(By.ID, "nav-runs").click()
        wait_for(lambda: chromium.find_element(By.ID, "live").text == "live")
        names = [r.get_attribute("data-run") for r in chromium.find_elements(By.CSS_SELECTOR, "#runs-body tr")]
        assert sorted(names) == ["a1", "a2", "b1"]
        assert all("finished" in r.text for r in chromium.find_elements(By.CSS_SELECTOR, "#runs-body tr"))
        chromium.save_screenshot(str(images / "runs.png"))
    finally:
        server.stop()


def test_a_live_run_shows_in_the_browser_within_2_s_of_its_journal(tmp_path, chromium, images):
    """``run --driver tcp://`` against ``serve-sim --realtime 1``: the page's journal count catches up within 2 s."""
    from selenium.common.exceptions import StaleElementReferenceException
    from selenium.webdriver.common.by import By

    from stableins.procedures.journal import scan

    env = dict(os.environ, MPLBACKEND="Agg")
    sim = subprocess.Popen([sys.executable, "-m", "stableins.cli", "serve-sim", "--port", "0", "--realtime", "1", "--unit", "SN-LIVE",
                            "--quiet"],
                           stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)  # fmt: skip
    runs = tmp_path / "runs"
    runs.mkdir()
    run = None
    server = None
    try:
        port = sim.stdout.readline().strip().rsplit(":", 1)[1]
        argv = [sys.executable, "-m", "stableins.cli", "run", "device-coarse", "--driver", f"tcp://127.0.0.1:{port}", "--unit", "SN-LIVE",
                "--out", str(runs / "live")]  # fmt: skip
        run = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, start_new_session=True)
        journal = runs / "live" / "journal.bin"
        wait_for(lambda: journal.exists() and len(scan(journal).records) >= 3, timeout=60)
        server = Server("--store", str(tmp_path / "store"), "--runs", str(runs))
        chromium.get(f"{server.url}/runs")
        wait_for(lambda: chromium.find_element(By.ID, "live").text == "live")

        def row_text(css: str) -> str | None:  # the live updates replace the rows: a row found may be gone when read
            try:
                found = chromium.find_elements(By.CSS_SELECTOR, css)
                return found[0].text if found else None
            except StaleElementReferenceException:
                return None

        def shown() -> int:
            text = row_text("#runs-body tr[data-run='live'] td.records")
            return int(text) if text else -1

        # the page follows the journal while the run goes on: each count the journal reaches, the page shows (the wait is
        # a bound against a hang, not a measurement: no wall-clock limit decides the verdict, issue 31)
        lags, counts = [], []
        for _ in range(3):
            count = len(scan(journal).records)  # what the journal holds now
            seen = time.monotonic()
            wait_for(lambda count=count: shown() >= count, timeout=120)
            lags.append(time.monotonic() - seen)
            counts.append(count)
            wait_for(lambda count=count: len(scan(journal).records) > count, timeout=120)  # the run writes on
        row = wait_for(lambda: row_text("#runs-body tr[data-run='live']"))
        assert "running" in row and "coarse" in row and "SN-LIVE" in row
        assert counts == sorted(set(counts))  # three different, growing journal lengths, each shown by the page
        chromium.save_screenshot(str(images / "runs-live.png"))
        print(f"page behind the journal by {[round(x, 3) for x in lags]} s (information, not a limit)")
    finally:
        if server is not None:
            server.stop()
        if run is not None:
            os.killpg(run.pid, signal.SIGTERM)
            run.wait(30)
        sim.terminate()
        sim.wait(30)
        sim.stdout.close()
