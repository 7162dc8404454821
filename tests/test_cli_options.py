"""Every CLI option in at least one successful run (issue 31): an explicit table option → test, checked against the parser.

The test walks the argparse parser of every command.  Each option is either in :data:`RUN_BY`, naming a test that
runs the command with it successfully (exit 0: the test's own source must hold the option), or in :data:`NOT_YET_RUN`,
the options no test runs successfully yet.  That list only shrinks: an option added to the parser must come with
its test in :data:`RUN_BY`, and an option moved to :data:`RUN_BY` must leave it.  The table was found by reading the
tests' ``main([...]) == 0`` calls (``--help`` and ``--version`` excluded).
"""

from __future__ import annotations

import argparse
import ast
from functools import cache
from pathlib import Path

import pytest

from stableins import cli

TESTS = Path(__file__).resolve().parent

#: ``"command --option"`` → ``"test_file.py::test_name"``: a test that runs the command with the option, exit 0.
RUN_BY: dict[str, str] = {
    "budget --compare": "test_navigation_budget.py::test_cli_budget_table_json_compare_and_plot",
    "budget --damping": "test_navigation_budget.py::test_cli_budget_table_json_compare_and_plot",
    "budget --drift": "test_navigation_budget.py::test_cli_budget_table_json_compare_and_plot",
    "budget --duration": "test_navigation_budget.py::test_budget_refuses_a_duration_without_a_unit",
    "budget --json": "test_navigation_budget.py::test_budget_refuses_a_duration_without_a_unit",
    "budget --latitude": "test_navigation_budget.py::test_cli_budget_table_json_compare_and_plot",
    "budget --plot": "test_navigation_budget.py::test_cli_budget_table_json_compare_and_plot",
    "calibrate device --add": "test_discovery_record.py::test_the_simulated_ins_applies_the_installed_discovered_terms",
    "calibrate device --bias-instability": "test_device_simulator.py::test_cli_calibrates_simulated_files_and_writes_a_record",
    "calibrate device --fine-procedure": "test_discovery_record.py::test_calibrate_device_add_writes_the_effect_its_verdict_and_a_procedure_adds_too",  # noqa: E501
    "calibrate device --json": "test_cli.py::test_group_dispatches_and_imports_only_the_invoked_module",
    "calibrate device --no-gyro": "test_gyro_sensitivity.py::test_calibrate_device_carries_the_gyro_numbers_into_the_record",
    "calibrate device --out": "test_device_badinput.py::test_cli_report_failure_leaves_no_record",
    "calibrate device --random-walk": "test_discovery_record.py::test_calibrate_device_add_writes_the_effect_its_verdict_and_a_procedure_adds_too",  # noqa: E501
    "calibrate device --report": "test_device_badinput.py::test_cli_report_failure_leaves_no_record",
    "calibrate drift --out": "test_run_truth.py::test_run_with_a_known_truth_keeps_it_and_calibrate_drift_recovers_its_drift",
    "calibrate drift --prior": "test_run_truth.py::test_run_with_a_known_truth_keeps_it_and_calibrate_drift_recovers_its_drift",
    "campaign --no-plot": "test_campaign.py::test_distributed_scheduler_and_worker_give_the_local_table_and_resume",
    "campaign --out": "test_campaign.py::test_distributed_scheduler_and_worker_give_the_local_table_and_resume",
    "campaign --workers": "test_campaign.py::test_distributed_scheduler_and_worker_give_the_local_table_and_resume",
    "check --json": "test_cli.py::test_check_json_output",
    "check --trust": "test_report.py::test_signed_certificate_verifies_and_one_changed_byte_fails_with_the_reason",
    "diagnose --add": "test_diagnose_library.py::test_device_document_round_trips",
    "diagnose --bin": "test_discovery_cli.py::test_diagnose_system_record",
    "diagnose --json": "test_diagnose_library.py::test_device_document_round_trips",
    "diagnose --plots": "test_discovery_cli.py::test_diagnose_text_and_plots",
    "diagnose --record": "test_diagnose_library.py::test_device_document_round_trips",
    "diagnose --stage": "test_report.py::test_pipeline_certificate_shows_the_fits_the_calibration_printed",
    "history --add": "test_truth.py::test_recal_writes_one_record_in_force_whose_certificate_shows_it",
    "history --at": "test_history_store.py::test_fleet_which_units_are_due_and_which_drift",
    "history --drifted": "test_history_store.py::test_fleet_which_units_are_due_and_which_drift",
    "history --due": "test_history_store.py::test_fleet_which_units_are_due_and_which_drift",
    "history --fleet": "test_history_store.py::test_fleet_which_units_are_due_and_which_drift",
    "history --json": "test_history_store.py::test_fleet_which_units_are_due_and_which_drift",
    "history --plot": "test_history.py::test_two_records_a_minute_apart_state_no_drift",
    "history --store": "test_history.py::test_two_records_a_minute_apart_state_no_drift",
    "noise --json": "test_noise_cli.py::test_noise_from_a_static_system_record_recovers_the_simulated_terms",
    "noise --plot": "test_noise_cli.py::test_noise_from_a_static_system_record_recovers_the_simulated_terms",
    "protocol-check --envelope": "test_protocol_check.py::test_serve_sim_conforms",
    "recal --estimate": "test_truth.py::test_recal_history_and_certificate_agree_on_every_change_flag",
    "recal --json": "test_truth.py::test_recal_history_and_certificate_agree_on_every_change_flag",
    "recal --out": "test_truth.py::test_recal_history_and_certificate_agree_on_every_change_flag",
    "recal --store": "test_truth.py::test_recal_history_and_certificate_agree_on_every_change_flag",
    "recal --unit": "test_truth.py::test_recal_history_and_certificate_agree_on_every_change_flag",
    "report --data": "test_report.py::test_pipeline_certificate_shows_the_fits_the_calibration_printed",
    "report --out": "test_report.py::test_sections_without_evidence_say_so",
    "report --procedure": "test_report.py::test_every_word_inside_the_page_and_optional_sections_render",
    "run --driver": "test_design.py::test_stableins_run_executes_the_designed_procedure_with_its_dwells",
    "run --json": "test_runner_console.py::test_run_cli_prints_the_certificates_conformity_and_a_finished_run_is_left_alone",
    "run --out": "test_design.py::test_stableins_run_executes_the_designed_procedure_with_its_dwells",
    "run --quiet": "test_recal_resume.py::test_recal_resume_of_a_plain_run_names_the_right_command",
    "run --re-estimate": "test_runner_console.py::test_run_cli_prints_the_certificates_conformity_and_a_finished_run_is_left_alone",
    "run --resume": "test_recal_resume.py::test_an_interrupted_recal_resumed_as_the_console_says_files_exactly_one_record",
    "run --seed": "test_recal_resume.py::test_recal_resume_of_a_plain_run_names_the_right_command",
    "run --unit": "test_design.py::test_stableins_run_executes_the_designed_procedure_with_its_dwells",
    "run --yes": "test_recal_resume.py::test_an_interrupted_recal_resumed_as_the_console_says_files_exactly_one_record",
    "simulate --duration": "test_cli.py::test_simulate_system_streams_a_valid_record",
    "simulate --json": "test_cli.py::test_simulate_list_effects",
    "simulate --list-effects": "test_cli.py::test_simulate_list_effects",
    "simulate --list-worlds": "test_worlds.py::test_cli_world_and_list",
    "simulate --out": "test_cli.py::test_simulate_system_streams_a_valid_record",
    "simulate --rate": "test_cli.py::test_simulate_system_streams_a_valid_record",
    "simulate --seed": "test_cli.py::test_simulate_system_streams_a_valid_record",
}
#: Options no test runs successfully yet (only shrinks; issue 31 counted 163 of 226 at first).
NOT_YET_RUN: frozenset[str] = frozenset(
    {
        "calibrate device --allow-missing",
        "calibrate device --alpha",
        "calibrate device --coarse-linear",
        "calibrate device --coarse-procedure",
        "calibrate device --keep-unsupported",
        "calibrate device --noise",
        "calibrate device --set",
        "calibrate drift --json",
        "calibrate drift --new-calibration",
        "calibrate drift --one-position",
        "calibrate drift --set",
        "calibrate lever --all-arms",
        "calibrate lever --json",
        "calibrate lever --new-calibration",
        "calibrate lever --no-asynchrony",
        "calibrate lever --out",
        "calibrate lever --prior",
        "calibrate lever --set",
        "calibrate lever --window",
        "calibrate poses --add",
        "calibrate poses --bias-instability",
        "calibrate poses --columns",
        "calibrate poses --detect-only",
        "calibrate poses --diagnose",
        "calibrate poses --false-split",
        "calibrate poses --gravity",
        "calibrate poses --holds",
        "calibrate poses --json",
        "calibrate poses --min-hold",
        "calibrate poses --noise",
        "calibrate poses --out",
        "calibrate poses --plot",
        "calibrate poses --random-walk",
        "calibrate poses --range",
        "calibrate poses --rate",
        "calibrate poses --serial",
        "calibrate poses --time-unit",
        "calibrate poses --units",
        "calibrate poses --window",
        "calibrate poses --write-holds",
        "calibrate poses --zero",
        "calibrate system --allow-gaps",
        "calibrate system --bias-instability",
        "calibrate system --case-rotation-period",
        "calibrate system --chunk-rows",
        "calibrate system --cross-coupling",
        "calibrate system --estimate-k2",
        "calibrate system --gyro-drift",
        "calibrate system --gyro-drift-uncertainty",
        "calibrate system --json",
        "calibrate system --new-calibration",
        "calibrate system --no-couplings",
        "calibrate system --no-loop-compensation",
        "calibrate system --noise",
        "calibrate system --out",
        "calibrate system --plot",
        "calibrate system --prior",
        "calibrate system --random-walk",
        "calibrate system --set",
        "calibrate system --systematic",
        "calibrate system --thermal-prior",
        "calibrate thermal --json",
        "calibrate thermal --new-calibration",
        "calibrate thermal --out",
        "calibrate thermal --prior",
        "calibrate thermal --set",
        "campaign --json",
        "campaign --scheduler",
        "check --allow-gaps",
        "demo --duration",
        "demo --hidden",
        "demo --json",
        "demo --out",
        "demo --rate",
        "demo --seed",
        "design --bias-instability",
        "design --budget",
        "design --criterion",
        "design --fine",
        "design --grid",
        "design --json",
        "design --match",
        "design --max-dwell",
        "design --min-dwell",
        "design --name",
        "design --noise",
        "design --out",
        "design --passes",
        "design --quantization",
        "design --random-walk",
        "design --sample-rate",
        "design --target",
        "design --white",
        "diagnose --allow-gaps",
        "diagnose --alpha",
        "diagnose --bias-instability",
        "diagnose --noise",
        "diagnose --random-walk",
        "diagnose --top",
        "history --max-age",
        "history --verify",
        "noise --confidence",
        "noise --out",
        "noise --record",
        "protocol-check --duration",
        "protocol-check --json",
        "protocol-check --timeout",
        "recal --chunk",
        "recal --driver",
        "recal --hidden",
        "recal --link-failures",
        "recal --new-calibration",
        "recal --no-file",
        "recal --prior",
        "recal --quiet",
        "recal --re-estimate",
        "recal --resume",
        "recal --retries",
        "recal --seed",
        "recal --set",
        "recal --timeout",
        "recal --truth",
        "recal --yes",
        "report --customer",
        "report --discovery",
        "report --json",
        "report --laboratory",
        "report --no-statement",
        "report --operator",
        "report --previous",
        "report --report-id",
        "report --sign",
        "report --sign-cert",
        "report --technical",
        "run --chunk",
        "run --hidden",
        "run --link-failures",
        "run --new-calibration",
        "run --prior",
        "run --retries",
        "run --set",
        "run --store",
        "run --timeout",
        "run --truth",
        "serve-sim --connections",
        "serve-sim --installed",
        "serve-sim --json",
        "serve-sim --port",
        "serve-sim --quiet",
        "serve-sim --rate",
        "serve-sim --realtime",
        "serve-sim --seed",
        "serve-sim --truth",
        "serve-sim --unit",
        "simulate --dwell",
        "simulate --format",
        "simulate --hidden",
        "simulate --installed",
        "simulate --no-iteration",
        "simulate --procedure",
        "simulate --settle",
        "simulate --truth",
        "simulate --world",
    }
)


def _commands(table, path=()):
    for name, entry in table.items():
        if isinstance(entry, cli.Group):
            yield from _commands(entry.commands, (*path, name))
        else:
            yield (*path, name)


@cache
def parser_options() -> frozenset[str]:
    """``"command --option"`` for every option of every command (its long spelling; --help excluded)."""
    found = set()
    for words in _commands(cli.COMMANDS):
        parser = cli.build_parser(list(words))
        for word in words:
            parser = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[word]
        for action in parser._actions:
            if action.option_strings and not isinstance(action, argparse._HelpAction):
                found.add(f"{' '.join(words)} {action.option_strings[-1]}")
    return frozenset(found)


def test_every_option_is_run_by_a_test_or_listed_as_not_yet() -> None:
    options = parser_options()
    assert not (set(RUN_BY) & NOT_YET_RUN), "an option now run by a test must leave NOT_YET_RUN"
    unknown = (set(RUN_BY) | NOT_YET_RUN) - options
    assert not unknown, f"options the parser no longer has: {sorted(unknown)}"
    missing = options - set(RUN_BY) - NOT_YET_RUN
    assert not missing, f"new options without a successful-run test in RUN_BY: {sorted(missing)}"


@cache
def _test_sources(file: str) -> dict[str, str]:
    tree = ast.parse((TESTS / file).read_text(encoding="utf-8"))
    source = (TESTS / file).read_text(encoding="utf-8")
    return {n.name: ast.get_source_segment(source, n) or "" for n in tree.body if isinstance(n, ast.FunctionDef)}


@pytest.mark.parametrize("option", sorted(RUN_BY))
def test_the_named_test_runs_the_option(option: str) -> None:
    file, _, name = RUN_BY[option].partition("::")
    sources = _test_sources(file)
    assert name in sources, f"{RUN_BY[option]} does not exist"
    spelling = option.rsplit(" ", 1)[1]
    assert f'"{spelling}"' in sources[name] and "== 0" in sources[name], f"{RUN_BY[option]} does not run {option} successfully"


def test_hypothesis_is_derandomized_suite_wide() -> None:
    """tests/conftest.py loads a derandomized profile: every hypothesis test sees the same cases every run."""
    from hypothesis import settings

    assert settings.default.derandomize and settings.default.database is None
