"""Run a campaign's tasks on Dask: a local cluster by default, or an existing scheduler; resumable.

Every finished task's rows are written by the client to ``OUT/tasks/<task>.json`` atomically (a rename of a
complete file), so an interrupted campaign, run again with the same file and directory, runs only the tasks that
have no file yet.  Workers need no shared disk: they receive the validated campaign (procedures loaded) and return
rows.  At most a bounded window of tasks is in flight, so a campaign of any size needs bounded memory.  A task's
rows depend only on its identity (:mod:`stableins.campaign.task`), hence the table is the same, task by task, for
any number of workers, local or distributed (the timing columns excepted).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from stableins.campaign.config import CampaignConfig, Task
from stableins.campaign.task import TaskData, run_task
from stableins.data.atomic import atomic_write
from stableins.errors import InputError

#: Tasks in flight per worker (the window bounds the client's memory, whatever the campaign's size).
IN_FLIGHT_PER_WORKER = 8
#: Seconds to wait for an existing scheduler and its first worker.
CONNECT_TIMEOUT = 30.0


@dataclass(frozen=True)
class CampaignRun:
    """What a run did: tasks in the campaign, found finished on disk, run now; the workers it had."""

    total: int
    resumed: int
    ran: int
    workers: int
    scheduler: str


def config_digest(config: CampaignConfig) -> str:
    """SHA-256 of the campaign file and every procedure file it names (a resumed campaign must use the same)."""
    h = hashlib.sha256(Path(config.path).read_bytes())
    for spec in config.procedures:
        for definition in (spec.coarse, spec.fine):
            if definition is not None:
                h.update(Path(definition.path).read_bytes())
    return h.hexdigest()


def _holds_campaign(config: CampaignConfig, out: Path) -> bool:
    """Whether ``out`` holds this campaign already (read only); :class:`InputError` if it holds another."""
    marker = out / "campaign.json"
    if not marker.exists():
        return False
    try:
        held = json.loads(marker.read_text(encoding="utf-8"))["digest"]
    except (OSError, ValueError, KeyError, TypeError):
        raise InputError("not a campaign's marker", path=marker, expected="the campaign.json that `stableins campaign` writes") from None
    if held != config_digest(config):
        raise InputError(
            "this directory holds a campaign of another file (or its procedures changed)",
            path=out,
            field="campaign.json",
            expected=f"the campaign with digest {held[:16]}…, or a new --out directory",
        )
    return True


def _claim_directory(config: CampaignConfig, out: Path) -> None:
    """Create ``out`` (or check that it holds this campaign) and write ``campaign.json`` with the digest."""
    if _holds_campaign(config, out):
        return
    (out / "tasks").mkdir(parents=True, exist_ok=True)
    with atomic_write(out / "campaign.json") as handle:
        json.dump(
            {"campaign": config.name, "file": config.path, "digest": config_digest(config), "tasks": len(config.tasks())},
            handle,
            indent=1,
        )


def task_file(out: Path, task: Task) -> Path:
    """Where a finished task's rows are kept."""
    return out / "tasks" / f"{task.key}.json"


def _save(out: Path, task: Task, rows: list[dict[str, Any]]) -> None:
    clean = [{k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in row.items()} for row in rows]
    with atomic_write(task_file(out, task)) as handle:
        json.dump(clean, handle)


def load_rows(out: Path, tasks: Sequence[Task]) -> list[dict[str, Any]]:
    """Return the rows of every finished task, in task order (NaN for the empty cells)."""
    rows = []
    for task in tasks:
        path = task_file(out, task)
        if path.exists():
            rows += [{k: (math.nan if v is None else v) for k, v in row.items()} for row in json.loads(path.read_text(encoding="utf-8"))]
    return rows


@contextmanager
def _client(scheduler: str | None, workers: int | None) -> Iterator[Any]:
    """Yield a Dask client: of ``scheduler`` (an address), else of a local cluster of ``workers`` processes on 127.0.0.1."""
    from distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT)
        except (OSError, TimeoutError, ValueError) as error:
            raise InputError(
                f"no Dask scheduler answers: {error}", field="--scheduler", expected="tcp://HOST:PORT of a running scheduler"
            ) from None
        with client:
            try:
                client.wait_for_workers(1, timeout=CONNECT_TIMEOUT)
            except (OSError, TimeoutError) as error:
                raise InputError(
                    f"the scheduler has no worker after {CONNECT_TIMEOUT:g} s: {error}",
                    field="--scheduler",
                    expected="a scheduler with at least one `dask worker` attached",
                ) from None
            yield client
        return
    n = workers or os.cpu_count() or 1
    with (
        LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None) as cluster,
        Client(cluster) as client,
    ):
        yield client


def run_campaign(
    config: CampaignConfig,
    out: str | Path,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> CampaignRun:
    """Run every task of ``config`` that ``out`` does not hold yet (module docstring).

    ``progress(done, total)`` is called as tasks finish (``done`` counts the tasks found on disk too).
    """
    from distributed import as_completed

    out = Path(out)
    _holds_campaign(config, out)  # another campaign's directory is refused before anything connects or is written
    tasks = config.tasks()
    pending = [t for t in tasks if not task_file(out, t).exists()]
    resumed = len(tasks) - len(pending)
    done = resumed
    if progress is not None:
        progress(done, len(tasks))
    if not pending:
        _claim_directory(config, out)
        return CampaignRun(len(tasks), resumed, 0, 0, "none (nothing to run)")
    with _client(scheduler, workers) as client:  # a scheduler that does not answer leaves nothing written
        _claim_directory(config, out)
        n_workers = max(1, len(client.scheduler_info()["workers"]))
        data = client.scatter(TaskData(config), broadcast=True)
        queue = iter(pending)
        window = as_completed()
        for task in _take(queue, IN_FLIGHT_PER_WORKER * n_workers):
            window.add(client.submit(run_task, task, data, key=f"stableins-task-{task.key}", pure=False))
        for future in window:
            rows = future.result()
            _save(out, _task_of(rows), rows)
            done += 1
            if progress is not None:
                progress(done, len(tasks))
            for nxt in _take(queue, 1):
                window.add(client.submit(run_task, nxt, data, key=f"stableins-task-{nxt.key}", pure=False))
        address = str(client.scheduler.address)
    return CampaignRun(len(tasks), resumed, len(pending), n_workers, address if scheduler else "local cluster")


def _take(queue: Iterator[Task], n: int) -> list[Task]:
    out = []
    for task in queue:
        out.append(task)
        if len(out) >= n:
            break
    return out


def _task_of(rows: list[dict[str, Any]]) -> Task:
    """Return the task a result belongs to, from its rows."""
    first = rows[0]
    return Task(int(first["seed"]), str(first["procedure"]), str(first["noise"]), str(first["hidden"]))
