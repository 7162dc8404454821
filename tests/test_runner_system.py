"""System-level static record through the runner: streamed into the journal, exported, resumable sample for sample."""

from __future__ import annotations

import numpy as np
import pytest

from stableins.console import Console
from stableins.data.system import open_system_record
from stableins.drivers.select import simulated_platform
from stableins.procedures.definition import load_procedure
from stableins.procedures.planning import plan_from_definition
from stableins.runs import resume_run, start_run

SHORT = """
[procedure]
name = "system-short"
stage = "system"
[record]
settle = 1.0
duration = 120.0
sample_rate = 10.0
[runner]
chunk = 15.0
[[person]]
before = 0
action = "confirm"
prompt = "static base?"
"""


class Crash(Exception):
    pass


def test_static_record_and_resume(tmp_path):
    path = tmp_path / "system.toml"
    path.write_text(SHORT)
    plan = plan_from_definition(load_procedure(path))
    reference = start_run(plan, tmp_path / "ref", driver_spec="sim", seed=2, unit="SYS-1", console=Console(yes=True, quiet=True))
    record = open_system_record(reference.dataset)
    data = record.read()
    assert len(data["time"]) == 1200 and record.sample_rate == 10.0
    assert np.all(np.isfinite(data["velocity_north"]))

    driver = simulated_platform(2, "SYS-1", 10.0)
    chunks = driver.static_record

    def crashing(duration, chunk):
        for k, piece in enumerate(chunks(duration, chunk)):
            if k == 4:
                raise Crash("power lost in the middle of the record")
            yield piece

    driver.static_record = crashing
    with pytest.raises(Crash):
        start_run(
            plan,
            tmp_path / "run",
            driver_spec="sim",
            seed=2,
            unit="SYS-1",
            console=Console(yes=True, quiet=True),
            driver=driver,
        )
    again = resume_run(tmp_path / "run", console=Console(yes=True, quiet=True))
    assert again.replayed > 4
    resumed = open_system_record(again.dataset).read()
    for name in data:
        np.testing.assert_array_equal(resumed[name], data[name], err_msg=name)
