"""Issue 32's acceptance of ``stableins serve``: a fleet of 1,000 units × 20 records loads in under 1 s per page.

Run:  .venv/bin/python benchmarks/bench_fleet.py [--units 1000] [--records 20] [--store DIR|postgresql://...] [--keep DIR]

It builds a history store of ``--units`` units with ``--records`` calibration records each (independent fine-stage
calibrations a month apart, every tenth unit drifting in bias_x; records filed through :meth:`HistoryStore.add_filings`,
as ``history --migrate`` files them), starts the application of ``stableins serve`` over a real socket (uvicorn on
127.0.0.1, a free port) and times each page and its JSON as a client sees it:

* ``/fleet`` and ``/api/fleet``: every unit (record in force, due date, drifting parameters with z, overdue first)
  from the store's index; the first request and the median of 5 more, each read from the store again (the server's
  2-second reuse of the fleet is turned off);
* ``/units/SERIAL`` and ``/api/units/SERIAL``: a unit's 20 records read verified by SHA-256, the 19 changes and
  every parameter's trend;
* ``/runs``: the run root (empty here).

It prints one line per page with the seconds and PASS when under 1 s, then the fleet page as the server serves it
(what it read of the store kept until a record is filed).  ``--store postgresql://...`` builds the fleet
in a PostgreSQL database (an empty one).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import socket
import statistics
import sys
import tempfile
import threading
import time
import urllib.request
from datetime import UTC, datetime, timedelta
from pathlib import Path

TARGET = 1.0
IDS = ("bias_x", "sf_x", "beta_xy")
SIGMAS = {"bias_x": 2e-5, "sf_x": 5e-6, "beta_xy": 5e-6}


def make_record(serial: str, created: datetime, values: dict[str, float]):
    """An independent calibration of one fine-stage run whose data end at ``created``."""
    import numpy as np

    from stableins.errormodel import known_terms
    from stableins.records import Calibration, CalibrationRecord, DeterminedBy, Parameter, StageRun
    from stableins.status import Determination

    stamp = created.isoformat()
    tag = hashlib.sha256(f"{serial} {stamp}".encode()).hexdigest()[:8]
    calibration = Calibration(f"cal-{stamp[:10]}-{tag}", "device-fine", "stableins benchmark", stamp)
    run = StageRun(f"fine-{tag}", "fine", calibration.id, "device-fine", "stableins benchmark", stamp, stamp, stamp)
    terms = known_terms()
    parameters = tuple(
        Parameter(pid, float(v), terms[pid].si_unit, SIGMAS[pid], "estimated", (DeterminedBy(run.id, Determination.ALONE),))
        for pid, v in values.items()
    )
    return CalibrationRecord(serial, parameters, np.diag([SIGMAS[pid] ** 2 for pid in values]), calibration, (run,))


def build(store_location: str, units: int, records: int, folder: Path) -> float:
    """File ``units`` × ``records`` records; return the seconds it took."""
    import numpy as np

    from stableins.history_store import HistoryStore
    from stableins.history_store.filing import read_filing

    rng = np.random.default_rng(32)
    start = time.perf_counter()
    # building the fleet is not what is measured: the record files are not fsync'ed one by one (the index's
    # transactions still are, by SQLite or PostgreSQL)
    fsync, os.fsync = os.fsync, lambda fd: None
    store = HistoryStore(store_location)
    first = datetime.now(UTC) - timedelta(days=30 * records)

    def filings():
        for u in range(units):
            serial = f"LAB-{u:04d}"
            drift = 2e-4 if u % 10 == 0 else 0.0  # bias_x drifting 2e-4 m/s^2 a year: 10 σ a year
            for k in range(records):
                when = first + timedelta(days=30 * k + u % 30)
                years = 30 * k / 365.25
                values = {
                    "bias_x": 1e-4 + drift * years + rng.normal(0, SIGMAS["bias_x"]),
                    "sf_x": 1.0 + rng.normal(0, SIGMAS["sf_x"]),
                    "beta_xy": rng.normal(0, SIGMAS["beta_xy"]),
                }
                path = folder / f"{serial}-{k}.json"
                make_record(serial, when, values).save(path)
                yield read_filing(path, prior="", evidence=None)
                path.unlink()

    try:
        store.add_filings(filings())
    finally:
        os.fsync = fsync
    return time.perf_counter() - start


def serve(store_location: str, run_root: Path, *, fleet_ttl: float):
    """Start the application on 127.0.0.1 (a free port) in a thread; return (base URL, server)."""
    import uvicorn

    from stableins.web.app import ServeSettings, create_app
    from stableins.web.security import Limits

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    # fleet_ttl=0: every request reads the fleet from the store again (nothing cached)
    limits = Limits(rate=1000.0, burst=1000)
    settings = ServeSettings(store=store_location, run_root=run_root, limits=limits, fleet_ttl=fleet_ttl)
    app = create_app(settings)
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", access_log=False))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    while not server.started:
        time.sleep(0.02)
    return f"http://127.0.0.1:{port}", server


def timed_cpu(url: str) -> tuple[float, float, bytes]:
    """Return (wall seconds, CPU seconds of this process: client and server, all threads, body) of one request."""
    start, cpu = time.perf_counter(), time.process_time()
    with urllib.request.urlopen(url, timeout=60) as answer:
        body = answer.read()
    return time.perf_counter() - start, time.process_time() - cpu, body


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--units", type=int, default=1000)
    parser.add_argument("--records", type=int, default=20)
    parser.add_argument("--store", help="a store to build the fleet in (default: a new SQLite store in a temporary folder)")
    parser.add_argument("--keep", help="build the SQLite store here and keep it")
    parser.add_argument("--reuse", action="store_true", help="time the pages of the --store given as it is (built before)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        location = args.store or args.keep or str(folder / "store")
        (folder / "runs").mkdir()
        if not args.reuse:
            seconds = build(location, args.units, args.records, folder)
            print(f"built {args.units} units x {args.records} records in {location}: {seconds:.1f} s")
        base, server = serve(location, folder / "runs", fleet_ttl=0.0)
        try:
            fleet = json.loads(timed_cpu(f"{base}/api/fleet")[2])
            assert len(fleet["shown"]) == args.units, fleet["units"]
            serial = fleet["shown"][0]["serial"]
            drifting = sum(bool(u["drifting"]) for u in fleet["shown"])
            print(f"fleet: {fleet['units']} units, {fleet['overdue']} overdue, {drifting} drifting (every tenth unit drifts by design)")
            worst = worst_cpu = 0.0
            print(f"load average of the machine: {' '.join(f'{v:.1f}' for v in os.getloadavg())} ({os.cpu_count()} cores); "
                  "CPU = seconds of CPU this process (server and client) spent on the request")  # fmt: skip
            for page in ("/fleet", "/api/fleet", f"/units/{serial}", f"/api/units/{serial}", "/runs", "/api/runs"):
                first, first_cpu, body = timed_cpu(base + page)
                again = [timed_cpu(base + page) for _ in range(5)]
                median = statistics.median(a[0] for a in again)
                cpu = statistics.median(a[1] for a in again)
                worst = max(worst, first, median)
                worst_cpu = max(worst_cpu, first_cpu, cpu)
                verdict = "PASS" if max(first, median) < TARGET else "FAIL"
                print(f"{page:<22} {len(body) / 1024:5.0f} KiB  first {first:6.3f} s (CPU {first_cpu:5.3f} s)  median of 5 more "
                      f"{median:6.3f} s (CPU {cpu:5.3f} s)  target < {TARGET:g} s: {verdict}")  # fmt: skip
        finally:
            server.should_exit = True
        # as served: the fleet's records in force and drifts kept until a record is filed (the due dates worked out anew)
        base, server = serve(location, folder / "runs", fleet_ttl=60.0)
        try:
            first = timed_cpu(f"{base}/fleet")[0]
            median = statistics.median(timed_cpu(f"{base}/fleet")[0] for _ in range(5))
            print(f"{'/fleet as served':<24} first {first:6.3f} s, then (no record filed meanwhile) median of 5 {median:6.3f} s")
        finally:
            server.should_exit = True
        print(f"slowest page: {worst:.3f} s ({'PASS' if worst < TARGET else 'FAIL'}); "
              f"most CPU for a page: {worst_cpu:.3f} s ({'PASS' if worst_cpu < TARGET else 'FAIL'})")  # fmt: skip
    return 0 if worst < TARGET else 1


if __name__ == "__main__":
    sys.exit(main())
