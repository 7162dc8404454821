"""The FastAPI application of ``stableins serve``: the fleet, unit and runs pages, and the same data as JSON under ``/api``.

Pages (HTML)                         JSON (OpenAPI at ``/api/openapi.json``)
``/fleet``                           ``/api/fleet``
``/units/{serial}``                  ``/api/units/{serial}``
``/runs``                            ``/api/runs``, ``/api/runs/{name}``, ``/api/runs/events`` (server-sent events)
``/units/{serial}/records/{sha256}``    a filed record, its bytes verified against the index on the way out
``/units/{serial}/documents/{sha256}``  a certificate or technical report of a filed record, verified on the way out

Each page is rendered on the server from the same documents the API returns (the browser needs no script to read
it); a page's script only draws the trend plots (Plotly, served from the installed package: no CDN) and applies the
live updates of the runs page.
"""

import asyncio
import hashlib
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from stableins.display import unit_text
from stableins.errors import InputError
from stableins.history_store import DRIFT_SIGMAS, HistoryStore, UnitStatus
from stableins.web.certificates import CertificateIndex
from stableins.web.fleet import FleetRow, fleet_rows, select, unit_document
from stableins.web.models import Fleet, RunProgress, Runs, Unit
from stableins.web.policy import Policy
from stableins.web.runs import RunWatcher
from stableins.web.security import Guard, Limits

PACKAGE = Path(__file__).resolve().parent
#: Seconds between two looks at the journals while an event stream is open.
EVENT_INTERVAL = 0.25
#: Seconds the fleet's records in force and drifts are reused, unless a record is filed meanwhile.
FLEET_TTL = 60.0


@dataclass
class ServeSettings:
    """What ``stableins serve`` serves and how."""

    store: str | Path | None = None
    run_root: Path | None = None
    policy: Policy = field(default_factory=Policy)
    token: str | None = None
    limits: Limits = field(default_factory=Limits)
    secure_cookie: bool = False
    #: seconds the fleet's records in force and drifts are reused unless a record is filed meanwhile (0: never)
    fleet_ttl: float = FLEET_TTL


class _Data:
    """The store, the certificate index and the run watcher; the fleet kept while the store's state is the same.

    :meth:`HistoryStore.fleet` (records in force, drifting parameters) depends on the store alone and is read again
    when a record is filed (:meth:`HistoryStore.state`) or after ``settings.fleet_ttl`` seconds; the due dates, which
    move with the clock, and the certificates found under the run root are worked out for every request.
    """

    def __init__(self, settings: ServeSettings) -> None:
        self.settings = settings
        self.store = HistoryStore(settings.store)
        self.certificates = CertificateIndex(settings.run_root)
        self.runs = RunWatcher(settings.run_root)
        self._units: tuple[float, tuple[int, int], list[UnitStatus]] | None = None

    def fleet(self) -> list[FleetRow]:
        from datetime import timedelta

        now = time.monotonic()
        state = self.store.state()
        if self._units is None or self._units[1] != state or now - self._units[0] >= self.settings.fleet_ttl:
            units = self.store.fleet(None, timedelta(days=self.settings.policy.default), DRIFT_SIGMAS)
            self._units = (now, state, units)
        self.certificates.refresh()
        return fleet_rows(self._units[2], self.settings.policy, self.certificates)

    def unit(self, serial: str) -> Unit:
        self.certificates.refresh()
        return unit_document(self.store, serial, self.settings.policy, self.certificates)

    def entry(self, serial: str, digest: str) -> Any:
        """Return the unit's entry of the record with SHA-256 ``digest`` (InputError: none filed for this unit)."""
        for entry in self.store.entries(serial):
            if entry.sha256 == digest:
                return entry
        raise InputError(f"no record with SHA-256 {digest[:64]!r} is filed for unit {serial!r}", field="sha256")

    def document(self, serial: str, digest: str) -> tuple[Any, bytes, Any]:
        """Return (the certificate, its bytes, the entry of its record) of the PDF with SHA-256 ``digest``, all verified.

        The PDF must be under the run root, name a record filed for ``serial`` whose bytes still have their SHA-256,
        and still have the SHA-256 it had when indexed.
        """
        self.certificates.refresh()
        found = self.certificates.by_sha256(digest)
        if found is None:
            raise InputError(f"no certificate with SHA-256 {digest[:64]!r} under the run root", field="sha256")
        entry = self.entry(serial, found.record_sha256)
        self.store.verified_data(serial, entry)  # the record it certifies is intact
        body = found.path.read_bytes()
        if hashlib.sha256(body).hexdigest() != found.sha256:
            raise InputError("the document changed since it was indexed", path=found.path.name, field="sha256", expected=found.sha256)
        return found, body, entry


def create_app(settings: ServeSettings) -> Any:
    """Return the ASGI application (FastAPI inside :class:`~stableins.web.security.Guard`)."""
    from fastapi import FastAPI, Request
    from fastapi.responses import JSONResponse, Response
    from fastapi.templating import Jinja2Templates

    import stableins

    data = _Data(settings)
    app = FastAPI(
        title="stableins serve",
        version=stableins.__version__,
        description="A laboratory's fleet of calibrated units, read-only (docs/fleet.md).",
        openapi_url="/api/openapi.json",
        docs_url=None,
        redoc_url=None,
    )
    templates = Jinja2Templates(directory=str(PACKAGE / "templates"))
    templates.env.globals["version"] = stableins.__version__
    templates.env.filters["days"] = _days
    templates.env.filters["unit"] = unit_text  # µg, ², °/h as the certificate prints them

    @app.exception_handler(InputError)
    async def _input_error(request: Request, error: InputError) -> Response:
        # 404: nothing of that name; 409: a record or document that fails its SHA-256 check; 400: anything else
        status = 404 if error.message.startswith("no ") else 409 if error.field == "sha256" else 400
        message = str(error)
        folders = [(settings.run_root, "RUNS")] + ([(data.store.root, "STORE")] if data.store.url is None else [])
        for folder, name in folders:  # no server paths in answers
            if folder is not None:
                message = message.replace(str(Path(folder).resolve()), name).replace(str(folder), name)
        if request.url.path.startswith("/api/") or "text/html" not in request.headers.get("accept", ""):
            return JSONResponse({"detail": message}, status_code=status)
        return templates.TemplateResponse(request, "error.html", {"message": message, "status": status}, status_code=status)

    _static_routes(app)
    _fleet_routes(app, data, templates)
    _unit_routes(app, data, templates)
    _run_routes(app, data, templates)
    return Guard(app, token=settings.token, limits=settings.limits, secure_cookie=settings.secure_cookie)


def _static_routes(app: Any) -> None:
    """Add the package's own static files: the style sheet, the pages' scripts, Plotly's JavaScript from its package."""
    from fastapi.responses import FileResponse, JSONResponse, RedirectResponse, Response

    @app.get("/static/plotly.min.js", include_in_schema=False)
    def plotly_js() -> Response:
        import plotly

        path = Path(plotly.__file__).parent / "package_data" / "plotly.min.js"
        return FileResponse(path, media_type="text/javascript", headers={"cache-control": "max-age=86400"})

    @app.get("/static/{name}", include_in_schema=False)
    def static(name: str) -> Response:
        files = {"app.css": "text/css", "unit.js": "text/javascript", "runs.js": "text/javascript"}
        if name not in files:  # only the package's own files, by name
            return JSONResponse({"detail": "not found"}, status_code=404)
        return FileResponse(PACKAGE / "static" / name, media_type=files[name])

    @app.get("/", include_in_schema=False)
    def root() -> Response:
        return RedirectResponse("/fleet")


def _fleet_routes(app: Any, data: _Data, templates: Any) -> None:
    """Add ``/fleet`` and ``/api/fleet``."""
    from fastapi import Query, Request
    from fastapi.responses import HTMLResponse, Response

    from stableins.web import models

    settings = data.settings

    def _fleet(q: str, *, overdue: bool, drifting: bool, conformity: str) -> Fleet:
        rows = data.fleet()
        shown = select(rows, search=q, overdue=overdue, drifting=drifting, conformity=conformity)
        return Fleet(
            store=data.store.location,
            units=len(rows),
            overdue=sum(r.overdue for r in rows),
            drifting=sum(bool(r.drifting) for r in rows),
            interval_source=settings.policy.source,
            shown=[r.to_json() for r in shown],
        )

    @app.get(
        "/api/fleet",
        response_model=models.Fleet,
        summary="Every unit: record in force, calibration and due dates, conformity, drifting parameters",
    )
    def api_fleet(
        *,
        q: str = Query("", max_length=100, description="serial number or procedure contains this (any case)"),
        overdue: bool = Query(False, description="only units past their due date"),
        drifting: bool = Query(False, description="only units with a parameter drifting beyond 3σ per year"),
        conformity: str = Query("", max_length=20, description="only units whose certificate states this (PASS, FAIL, ...)"),
    ) -> Fleet:
        """Return the units overdue first (most overdue first), then by due date.

        ``drifting`` gives each drifting parameter's significance z = drift / σ per year (``stableins history --fleet``).
        """
        return _fleet(q, overdue=overdue, drifting=drifting, conformity=conformity)

    @app.get("/fleet", response_class=HTMLResponse, include_in_schema=False)
    def fleet_page(request: Request, *, q: str = Query("", max_length=100), overdue: bool = False, drifting: bool = False,
                   conformity: str = Query("", max_length=20)) -> Response:  # fmt: skip
        document = _fleet(q, overdue=overdue, drifting=drifting, conformity=conformity)
        filters = {"q": q, "overdue": overdue, "drifting": drifting, "conformity": conformity}
        return templates.TemplateResponse(
            request, "fleet.html", {"fleet": document.model_dump(by_alias=True), "filters": filters, "page": "fleet"}
        )


def _unit_routes(app: Any, data: _Data, templates: Any) -> None:
    """Add ``/units/{serial}``, ``/api/units/{serial}`` and the verified downloads of records and documents."""
    from fastapi import Request
    from fastapi.responses import HTMLResponse, Response

    from stableins.web import models

    @app.get(
        "/api/units/{serial}",
        response_model=models.Unit,
        summary="A unit's records, their certificates, the changes between them and every parameter's trend",
    )
    def api_unit(serial: str) -> Unit:
        """Return the unit's records (each read verified by its SHA-256), changes and trends.

        Changes carry z = change / σ of the change (the certificate's statistic); trends the data-only points with σ, the
        fitted line and its z (``stableins history``).
        """
        return data.unit(serial)

    @app.get("/units/{serial}", response_class=HTMLResponse, include_in_schema=False)
    def unit_page(request: Request, serial: str) -> Response:
        document = data.unit(serial)
        shown = [{**trend.model_dump(by_alias=True), "unit": unit_text(trend.unit)} for trend in document.trends]
        plots = json.dumps(shown).replace("</", "<\\/")
        page = document.model_dump(by_alias=True)  # the template reads the JSON keys ("from")
        return templates.TemplateResponse(request, "unit.html", {"unit": page, "plots": plots, "page": "fleet"})

    @app.get("/units/{serial}/records/{sha256}", summary="A filed record, its SHA-256 verified against the index on the way out")
    def record_file(serial: str, sha256: str) -> Response:
        entry = data.entry(serial, sha256)
        body = data.store.verified_data(serial, entry)
        return Response(body, media_type="application/json", headers=_download(entry.file, body, record=entry.sha256))

    @app.get("/units/{serial}/documents/{sha256}", summary="A certificate or technical report of a filed record, verified on the way out")
    def document_file(serial: str, sha256: str, *, inline: bool = False) -> Response:
        """Return the PDF, which must name a record filed for this unit (read verified) and still have its indexed SHA-256.

        The response names both digests (``X-Record-SHA256``, ``X-Content-SHA256``); ``?inline=true`` opens it in the
        browser instead of saving it.
        """
        found, body, entry = data.document(serial, sha256)
        headers = _download(found.path.name, body, record=entry.sha256)
        if inline:  # opened in the browser's PDF viewer rather than saved
            headers["content-disposition"] = headers["content-disposition"].replace("attachment", "inline", 1)
        return Response(body, media_type="application/pdf", headers=headers)


def _run_routes(app: Any, data: _Data, templates: Any) -> None:
    """Add ``/runs``, ``/api/runs``, ``/api/runs/{name}`` and the event stream ``/api/runs/events``."""
    from fastapi import Request
    from fastapi.concurrency import run_in_threadpool
    from fastapi.responses import HTMLResponse, Response, StreamingResponse

    from stableins.web import models

    settings = data.settings

    @app.get(
        "/api/runs",
        response_model=models.Runs,
        summary="Every run under the run root with its progress, running ones first",
    )
    def api_runs() -> Runs:
        return Runs(run_root=str(settings.run_root) if settings.run_root else None, runs=data.runs.all())

    @app.get("/api/runs/events", summary="Server-sent events: the runs' progress, sent when it changes (text/event-stream)")
    async def run_events(request: Request) -> Response:
        async def stream() -> Any:
            last = ""
            quiet = 0.0
            while not await request.is_disconnected():
                runs = await run_in_threadpool(data.runs.all)
                text = json.dumps({"runs": _dumped(runs)})
                if text != last:
                    last, quiet = text, 0.0
                    yield f"event: runs\ndata: {text}\n\n"
                elif quiet > 15.0:
                    quiet = 0.0
                    yield ": keep-alive\n\n"
                await asyncio.sleep(EVENT_INTERVAL)
                quiet += EVENT_INTERVAL

        return StreamingResponse(stream(), media_type="text/event-stream", headers={"cache-control": "no-cache"})

    @app.get(
        "/api/runs/{name:path}",
        response_model=models.RunProgress,
        summary="One run's progress: stage, position, dwell, samples, remaining time, quick look",
    )
    def api_run(name: str) -> RunProgress:
        return data.runs.progress(name)

    @app.get("/runs", response_class=HTMLResponse, include_in_schema=False)
    def runs_page(request: Request) -> Response:
        runs = _dumped(data.runs.all())
        initial = json.dumps({"runs": runs}).replace("</", "<\\/")
        return templates.TemplateResponse(request, "runs.html", {"runs": runs, "initial": initial, "page": "runs",
                                                                  "run_root": settings.run_root})  # fmt: skip


def _dumped(runs: list[RunProgress]) -> list[dict[str, object]]:
    """Return the runs' progress as the JSON values the API sends (the JSON keys: "pass"), for the pages and events."""
    return [r.model_dump(by_alias=True) for r in runs]


def _days(days: float) -> str:
    """Return a span of days for people: whole days from one day on, else hours (or minutes, seconds)."""
    days = abs(days)
    if days >= 1.0:
        return f"{days:.0f} d"
    seconds = days * 86400.0
    if seconds >= 3600.0:
        return f"{seconds / 3600.0:.0f} h"
    return f"{seconds / 60.0:.0f} min" if seconds >= 60.0 else f"{seconds:.0f} s"


def _download(name: str, body: bytes, *, record: str) -> dict[str, str]:
    """Headers of a verified download: its name, its SHA-256 and the SHA-256 of the record it is or certifies."""
    safe = "".join(c for c in name if c.isalnum() or c in "-_.") or "download"
    return {
        "content-disposition": f'attachment; filename="{safe}"',
        "x-content-sha256": hashlib.sha256(body).hexdigest(),
        "x-record-sha256": record,
    }
