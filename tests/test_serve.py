"""``stableins serve`` without a browser (issue 32): the JSON API, the same numbers as ``history``, and its security.

Read-only, paths from URLs that never leave the store or the run root, request sizes and rates limited, a token
required when it is given (and refused start-up without one beyond the loopback interface), every download verified
by its SHA-256.  The progress of a run is read from a journal written here as the runner writes it.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import subprocess
import sys
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np
import pytest
from test_history_store import record

from stableins import cli
from stableins.errors import InputError
from stableins.history_store import HistoryStore

pytest.importorskip("fastapi", reason="FastAPI is not installed: pip install -e '.[test]'")
pytest.importorskip("httpx2", reason="httpx2 (Starlette's test client) is not installed: pip install -e '.[test]'")

from fastapi.testclient import TestClient  # noqa: E402

from stableins.web.app import ServeSettings, create_app  # noqa: E402
from stableins.web.policy import Policy  # noqa: E402
from stableins.web.security import Limits  # noqa: E402

TOKEN = "s3cret-token-of-the-lab-0123456789"


@pytest.fixture()
def lab(tmp_path):
    """A store of three units (DRIFTER drifts, OLD is overdue) and a run root with a journal written step by step."""
    store = HistoryStore(tmp_path / "store")
    for k in range(5):
        path = tmp_path / f"drift{k}.json"
        record("DRIFTER", 400 + 60 * k, values=(1e-4 + k * 1e-4, 1.0)).save(path)
        store.add(path)
    for k in range(2):
        path = tmp_path / f"steady{k}.json"
        record("STEADY", 500 + 90 * k).save(path)
        store.add(path)
    path = tmp_path / "old.json"
    record("OLD", 0).save(path)
    store.add(path)
    (tmp_path / "runs").mkdir()
    (tmp_path / "outside").mkdir()
    (tmp_path / "outside" / "secret.txt").write_text("not to be served", encoding="utf-8")
    return tmp_path


def client(lab: Path, **settings) -> TestClient:
    defaults = {"store": lab / "store", "run_root": lab / "runs"}
    return TestClient(create_app(ServeSettings(**{**defaults, **settings})))


def _cli_json(argv: list[str]) -> dict:
    buffer = io.StringIO()
    with redirect_stdout(buffer):
        assert cli.main([*argv, "--json"]) == 0
    return json.loads(buffer.getvalue())


def test_the_fleet_overdue_first_with_the_drift_of_history(lab):
    fleet = client(lab).get("/api/fleet").json()
    serials = [u["serial"] for u in fleet["shown"]]
    assert serials[0] == "OLD" and fleet["shown"][0]["overdue"] and set(serials) == {"OLD", "DRIFTER", "STEADY"}
    history = {u["serial"]: u for u in _cli_json(["history", "--fleet", "--store", str(lab / "store")])["units"]}
    for unit in fleet["shown"]:  # the same drifting parameters and z as `history --fleet`
        assert unit["drifting"] == history[unit["serial"]]["drifting"]
        assert unit["in_force"] == history[unit["serial"]]["in_force"]
    assert [d["id"] for d in next(u for u in fleet["shown"] if u["serial"] == "DRIFTER")["drifting"]] == ["bias_x"]
    only = client(lab).get("/api/fleet", params={"drifting": "true"}).json()["shown"]
    assert [u["serial"] for u in only] == ["DRIFTER"]
    assert [u["serial"] for u in client(lab).get("/api/fleet", params={"q": "stea"}).json()["shown"]] == ["STEADY"]
    page = client(lab).get("/fleet")
    assert page.status_code == 200 and page.text.index("OLD") < page.text.index("DRIFTER")


def test_a_policy_sets_the_due_dates(lab):
    (lab / "policy.toml").write_text("[interval]\ndefault = 36500\n[interval.procedure]\ndevice-fine = 30000\n", encoding="utf-8")
    policy = Policy.load(lab / "policy.toml")
    fleet = client(lab, policy=policy).get("/api/fleet").json()
    assert fleet["overdue"] == 0 and fleet["interval_source"] == str(lab / "policy.toml")
    (lab / "bad.toml").write_text("[interval]\ndefault = -3\n", encoding="utf-8")
    with pytest.raises(InputError, match="interval.default"):
        Policy.load(lab / "bad.toml")


def test_a_unit_has_the_changes_and_trends_of_history(lab):
    unit = client(lab).get("/api/units/DRIFTER").json()
    history = _cli_json(["history", "DRIFTER", "--store", str(lab / "store")])
    assert [r["sha256"] for r in unit["records"]] == [e["sha256"] for e in history["entries"]]
    for shown, told in zip(unit["changes"], history["changes"], strict=True):
        z = {p["id"]: p["significance"] for p in shown["parameters"]}
        assert z == pytest.approx({p["id"]: p["significance"] for p in told["parameters"]}, rel=1e-12)
        assert shown["significant"] == told["significant"]
    trend = {t["id"]: t for t in unit["trends"]}["bias_x"]
    told = {t["id"]: t for t in history["trends"]}["bias_x"]
    assert trend["significance"] == pytest.approx(told["significance"], rel=1e-12)
    assert len(trend["values"]) == len(trend["sigmas"]) == len(trend["line"]) == 5
    page = client(lab).get("/units/DRIFTER")
    assert page.status_code == 200
    assert trend["unit"] == "ug"  # the API keeps the record's unit; the page prints it as the certificate does
    assert "µg/year" in page.text and "[µg]" in page.text and "ug/year" not in page.text and "[ug]" not in page.text


def test_records_download_verified_and_a_tampered_one_is_refused(lab):
    store = HistoryStore(lab / "store")
    entry = store.entries("STEADY")[-1]
    answer = client(lab).get(f"/units/STEADY/records/{entry.sha256}")
    assert answer.status_code == 200 and hashlib.sha256(answer.content).hexdigest() == entry.sha256
    assert answer.headers["x-content-sha256"] == entry.sha256 and "attachment" in answer.headers["content-disposition"]
    path = lab / "store" / "STEADY" / entry.file
    path.write_bytes(path.read_bytes().replace(b'"STEADY"', b'"STEADY" '))
    refused = client(lab).get(f"/units/STEADY/records/{entry.sha256}")
    assert refused.status_code == 409 and "changed after it was filed" in refused.json()["detail"]
    assert str(lab) not in refused.json()["detail"] and "STORE/STEADY/" in refused.json()["detail"]  # no server paths
    assert client(lab).get("/api/units/STEADY").status_code == 409  # the unit's page reads its records verified too
    assert client(lab).get(f"/units/OLD/records/{entry.sha256}").status_code == 404  # another unit's record


@pytest.mark.parametrize(
    "target",
    [
        "/api/runs/../../outside/secret.txt",
        "/api/runs/..%2F..%2Foutside%2Fsecret.txt",
        "/api/runs/%2e%2e/outside",
        "/api/units/..%2Foutside",
        "/units/..%2F..%2Foutside/records/" + "0" * 64,
        "/static/..%2Fapp.py",
        "/static/%2e%2e/%2e%2e/outside/secret.txt",
        "/units/STEADY/documents/" + "0" * 64,
    ],
)
def test_paths_from_urls_never_leave_the_store_or_the_run_root(lab, target):
    answer = client(lab).get(target)
    assert answer.status_code in (400, 404, 405, 422)
    assert b"not to be served" not in answer.content and b"def " not in answer.content


def test_a_run_linked_from_outside_the_run_root_is_not_served(lab):
    outside = lab / "outside" / "run"
    outside.mkdir()
    (outside / "journal.bin").write_bytes(b"STABLEINS-JOURNAL 1\n")
    (outside / "procedure.json").write_text("{}", encoding="utf-8")
    os.symlink(outside, lab / "runs" / "linked")
    assert client(lab).get("/api/runs").json()["runs"] == []
    assert client(lab).get("/api/runs/linked").status_code == 404


def test_head_answers_what_get_would_without_the_body(lab):
    c = client(lab)
    for path in ("/fleet", "/api/fleet", "/units/DRIFTER", "/api/units/DRIFTER"):
        got, head = c.get(path), c.head(path)
        assert head.status_code == got.status_code == 200, path
        assert head.content == b"" and head.headers["content-type"] == got.headers["content-type"], path
        assert head.headers["content-security-policy"] == got.headers["content-security-policy"]
    assert c.head("/api/units/NOBODY").status_code == c.get("/api/units/NOBODY").status_code == 404
    stream = c.head("/api/runs/events")  # a stream's head is answered without opening the stream
    assert stream.status_code == 200 and stream.headers["content-type"] == "text/event-stream" and stream.content == b""


def test_read_only_and_request_sizes(lab):
    c = client(lab)
    for method in ("post", "put", "delete", "patch"):
        assert getattr(c, method)("/api/fleet").status_code == 405
    assert c.request("GET", "/api/fleet", content=b"x" * 10).status_code == 413
    assert c.get("/api/fleet?q=" + "a" * 3000).status_code == 414
    headers = {f"x-h{k}": "1" for k in range(80)}
    assert c.get("/api/fleet", headers=headers).status_code == 431
    answer = c.get("/fleet")
    assert "default-src 'self'" in answer.headers["content-security-policy"] and answer.headers["x-frame-options"] == "DENY"


def test_rate_limit(lab):
    c = client(lab, limits=Limits(rate=0.5, burst=5))
    codes = [c.get("/api/runs").status_code for _ in range(7)]
    assert codes[:5] == [200] * 5 and codes[5:] == [429, 429]
    assert int(c.get("/api/runs").headers["retry-after"]) >= 1


def test_a_token_is_required_when_given(lab):
    c = client(lab, token=TOKEN)
    assert c.get("/api/fleet").status_code == 401
    assert c.get("/api/fleet", headers={"authorization": "Bearer wrong-token-0123456789"}).status_code == 401
    assert c.get("/api/fleet", headers={"authorization": f"Bearer {TOKEN}"}).status_code == 200
    first = c.get(f"/fleet?token={TOKEN}")  # a browser's first visit: the token becomes an HttpOnly cookie
    assert first.status_code == 200 and "HttpOnly" in first.headers["set-cookie"]
    assert c.get("/units/OLD").status_code == 200  # the cookie carries it from now on


def test_serve_refuses_to_listen_beyond_localhost_without_a_token(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "STABLEINS_SERVE_TOKEN"}
    argv = [sys.executable, "-m", "stableins.cli", "serve", "--host", "0.0.0.0", "--store", str(tmp_path), "--port", "0"]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=60, env=env)
    assert done.returncode == 2 and "needs a token" in done.stderr and "Traceback" not in done.stderr
    (tmp_path / "token").write_text("short", encoding="utf-8")
    done = subprocess.run([*argv, "--token-file", str(tmp_path / "token")], capture_output=True, text=True, timeout=60, env=env)
    assert done.returncode == 2 and "too short" in done.stderr


def test_the_openapi_document_lists_the_api(lab):
    document = client(lab).get("/api/openapi.json").json()
    paths = document["paths"]
    assert {"/api/fleet", "/api/units/{serial}", "/api/runs", "/api/runs/events", "/api/runs/{name}"} <= set(paths)
    assert all(set(operations) == {"get"} for operations in paths.values())
    schemas = document["components"]["schemas"]
    assert {"Fleet", "FleetUnit", "Unit", "RecordChange", "TrendSeries", "RunProgress", "QuickLookDocument"} <= set(schemas)
    assert "significance" in schemas["Drifting"]["properties"] and "pass" in schemas["RunProgress"]["properties"]


def _plan(rate: float) -> dict:
    step = {"name": "coarse", "kind": "offset_iteration", "stage": "coarse", "positions": [1, 2, 3], "settles": [1.0] * 3,
            "dwells": [4.0] * 3}  # fmt: skip
    dwell = {"name": "check", "kind": "dwell", "stage": "fine", "pass_number": 1, "position": 7, "settle": 2.0, "dwell": 10.0}
    return {"name": "test-procedure", "sample_rate": rate, "chunk": 1.0, "steps": [step, dwell]}


def _acquire(journal, step: int, phase: str, n: int, t0: float) -> float:
    arrays = {"time": t0 + np.arange(n) / 10.0, "specific_force": np.zeros((n, 3)), "angles": np.zeros((n, 3)), "temperature": np.zeros(n)}
    journal.append("op", {"step": step, "attempt": 1, "phase": phase, "operation": "acquire", "arguments": [n / 10.0]}, arrays)
    return t0 + n / 10.0


def test_a_runs_progress_is_read_from_its_journal_as_it_grows(lab):
    from stableins.procedures.journal import Journal

    folder = lab / "runs" / "day1" / "r1"
    folder.mkdir(parents=True)
    (folder / "procedure.json").write_text(json.dumps(_plan(10.0)), encoding="utf-8")
    journal = Journal.create(folder / "journal.bin", ("start", {"unit": "SN-9", "utc": "2026-01-01T00:00:00+00:00"}))
    c = client(lab)
    first = c.get("/api/runs/day1/r1").json()
    assert (first["state"], first["unit"], first["step"], first["samples"]) == ("running", "SN-9", None, 0)
    assert first["remaining_seconds"] == pytest.approx(2 * 15.0 + 12.0) and first["remaining_is_lower_bound"]
    t = 0.0
    for position in range(4):  # the iteration: pass 1 over three positions, then the first of pass 2
        journal.append("op", {"step": 0, "attempt": 1, "phase": "iteration", "operation": "command", "arguments": [0.0, 0.0, 0.0],
                              "result": t})  # fmt: skip
        for _ in range(5 if position < 3 else 2):
            t = _acquire(journal, 0, "iteration", 10, t)
    now = c.get("/api/runs/day1/r1").json()
    assert (now["step"], now["stage"], now["position"], now["pass"]) == (1, "coarse", 1, 2)
    assert now["samples"] == 170 and now["dwell_seconds"] == pytest.approx(2.0) and now["dwell_planned"] == 5.0
    assert now["remaining_seconds"] == pytest.approx(30.0 - 17.0 + 12.0)
    journal.append("iteration", {"step": 0, "passes": 2})
    journal.append("op", {"step": 1, "attempt": 1, "operation": "command", "arguments": [0.0, 0.0, 0.0], "result": t})
    for _ in range(3):
        t = _acquire(journal, 1, "dwell", 10, t)
    later = c.get("/api/runs").json()["runs"][0]
    assert (later["name"], later["step"], later["stage"], later["position"], later["samples"]) == ("day1/r1", 2, "fine", 7, 200)
    assert later["remaining_seconds"] == pytest.approx(12.0 - 3.0) and not later["remaining_is_lower_bound"]
    journal.append("complete", {"step": 2})
    journal.append("finished", {"utc": "2026-01-01T01:00:00+00:00", "files": []})
    journal.close()
    done = c.get("/api/runs/day1/r1").json()
    assert done["state"] == "finished" and done["remaining_seconds"] == 0.0 and done["journal_records"] == 29
    (folder / "journal.bin").unlink()  # another run in the same directory: read from its start
    Journal.create(folder / "journal.bin", ("start", {"unit": "SN-10", "utc": "2026-01-02T00:00:00+00:00"})).close()
    again = c.get("/api/runs/day1/r1").json()
    assert (again["unit"], again["state"], again["journal_records"], again["samples"]) == ("SN-10", "running", 1, 0)


def test_a_static_records_quick_look_is_the_runners(lab):
    """The runs page's quick look of a system-level static record is the runner's own QuickLook over the journaled chunks."""
    from stableins.conventions import EARTH_RATE
    from stableins.procedures.journal import Journal
    from stableins.procedures.quicklook import QuickLook

    folder = lab / "runs" / "day"
    folder.mkdir()
    step = {"name": "one day", "kind": "static_record", "settle": 0.0, "duration": 7200.0, "checks": {"angle_tolerance": 1e-4}}
    (folder / "procedure.json").write_text(json.dumps({"name": "system-static", "sample_rate": 1.0, "steps": [step]}), encoding="utf-8")
    journal = Journal.create(folder / "journal.bin", ("start", {"unit": "SN-DAY", "utc": "2026-01-01T00:00:00+00:00"}))
    rng = np.random.default_rng(5)
    look = QuickLook(1.0, 1e-4)
    for k in range(12):  # 12 chunks of 300 s at 1 Hz: an hour
        t = k * 300.0 + np.arange(300.0)
        chunk = {"time": t, "velocity_north": 0.02 * np.cos(EARTH_RATE * t) + rng.normal(0, 1e-3, t.size),
                 "velocity_east": 0.01 * np.sin(EARTH_RATE * t) + rng.normal(0, 1e-3, t.size), "angle_platform": np.zeros(t.size),
                 "angle_inner": np.zeros(t.size), "angle_middle": np.zeros(t.size)}  # fmt: skip
        journal.append("op", {"step": 0, "attempt": 1, "phase": "static", "operation": "static_chunk", "arguments": [float(k)]}, chunk)
        look.update(chunk)
    journal.close()
    run = client(lab).get("/api/runs/day").json()
    assert (run["stage"], run["samples"], run["position"]) == ("system", 3600, None)
    assert run["quicklook"]["text"] == look.describe() and run["quicklook"]["hours"] == pytest.approx(1.0)
    assert run["remaining_seconds"] == pytest.approx(3600.0)
    page = client(lab).get("/runs")
    assert "SN-DAY" in page.text
