"""Every CLI option in at least one successful run (issue 31): an explicit table option → test, checked against the parser.

The test walks the argparse parser of every command.  Each option is either in :data:`RUN_BY`, naming a test that
runs the command with it successfully (exit 0; the test, or a helper of its file that it calls, spells the option), or in
:data:`NOT_YET_RUN`,
the options no test runs successfully yet.  That list only shrinks: an option added to the parser must come with
its test in :data:`RUN_BY`, and an option moved to :data:`RUN_BY` must leave it.  The table was found by reading the
tests' argument lists in tests that check an exit status of 0 (``--help`` excluded); that the run asserts the option's
effect is each named test's business, not checked here.
"""

from __future__ import annotations

import argparse
import ast
import json
from functools import cache
from pathlib import Path

import pytest
from inprocess import run_cli

from stableins import cli

TESTS = Path(__file__).resolve().parent

#: ``"command --option"`` → ``"test_file.py::test_name"``: a test that runs the command with the option, exit 0.
RUN_BY: dict[str, str] = {
    "recal --operator": "test_recal_resume.py::test_an_interrupted_recal_resumed_as_the_console_says_files_exactly_one_record",
    "recal --no-file": "test_history.py::test_recal_asks_for_the_operator_laboratory_and_customer",
    "recal --laboratory": "test_recal_resume.py::test_an_interrupted_recal_resumed_as_the_console_says_files_exactly_one_record",
    "recal --customer": "test_recal_resume.py::test_an_interrupted_recal_resumed_as_the_console_says_files_exactly_one_record",
    "history --migrate": "test_history_postgres.py::test_the_same_history_output_as_sqlite_and_migration_both_ways",
    "calibrate device --set": "test_cli_options.py::test_calibrate_device_options",
    "calibrate device --noise": "test_cli_options.py::test_calibrate_device_options",
    "calibrate device --keep-unsupported": "test_cli_options.py::test_calibrate_device_options",
    "calibrate device --coarse-procedure": "test_cli_options.py::test_calibrate_device_options",
    "calibrate device --coarse-linear": "test_cli_options.py::test_calibrate_device_options",
    "calibrate device --alpha": "test_cli_options.py::test_calibrate_device_options",
    "calibrate device --allow-missing": "test_cli_options.py::test_calibrate_device_options",
    "demo --quiet": "test_demo_cli.py::test_demo_runs_to_completion_with_every_option_and_its_verdict_holds",
    "demo --json": "test_demo_cli.py::test_demo_runs_to_completion_with_every_option_and_its_verdict_holds",
    "demo --hidden": "test_demo_cli.py::test_demo_runs_to_completion_with_every_option_and_its_verdict_holds",
    "demo --rate": "test_demo_cli.py::test_demo_runs_to_completion_with_every_option_and_its_verdict_holds",
    "demo --duration": "test_demo_cli.py::test_demo_runs_to_completion_with_every_option_and_its_verdict_holds",
    "demo --seed": "test_demo_cli.py::test_demo_runs_to_completion_with_every_option_and_its_verdict_holds",
    "demo --out": "test_demo_cli.py::test_demo_runs_to_completion_with_every_option_and_its_verdict_holds",
    "history --verify": "test_cli_options.py::test_history_verify_finds_a_changed_record",
    "noise --confidence": "test_cli_options.py::test_noise_confidence_sets_the_interval",
    "report --json": "test_cli_options.py::test_report_identification_statement_and_technical_options",
    "report --technical": "test_cli_options.py::test_report_identification_statement_and_technical_options",
    "report --no-statement": "test_cli_options.py::test_report_identification_statement_and_technical_options",
    "report --report-id": "test_cli_options.py::test_report_identification_statement_and_technical_options",
    "report --customer": "test_cli_options.py::test_report_identification_statement_and_technical_options",
    "report --laboratory": "test_cli_options.py::test_report_identification_statement_and_technical_options",
    "budget --compare": "test_navigation_budget.py::test_cli_budget_table_json_compare_and_plot",
    "budget --damping": "test_navigation_budget.py::test_cli_budget_table_json_compare_and_plot",
    "budget --drift": "test_navigation_budget.py::test_cli_budget_table_json_compare_and_plot",
    "budget --duration": "test_navigation_budget.py::test_budget_refuses_a_duration_without_a_unit",
    "budget --json": "test_navigation_budget.py::test_budget_refuses_a_duration_without_a_unit",
    "budget --latitude": "test_navigation_budget.py::test_cli_budget_table_json_compare_and_plot",
    "budget --plot": "test_navigation_budget.py::test_cli_budget_table_json_compare_and_plot",
    "calibrate device --add": "test_discovery_record.py::test_calibrate_device_add_writes_the_effect_its_verdict_and_a_procedure_adds_too",
    "calibrate device --bias-instability": "test_device_simulator.py::test_cli_calibrates_simulated_files_and_writes_a_record",
    "calibrate device --fine-procedure": "test_discovery_record.py::test_calibrate_device_add_writes_the_effect_its_verdict_and_a_procedure_adds_too",  # noqa: E501
    "calibrate device --json": "test_cli.py::test_group_dispatches_and_imports_only_the_invoked_module",
    "calibrate device --no-gyro": "test_gyro_sensitivity.py::test_calibrate_device_carries_the_gyro_numbers_into_the_record",
    "calibrate device --out": "test_bad_input.py::test_two_second_dwells_give_a_flagged_result_not_a_traceback",
    "calibrate device --random-walk": "test_discovery_record.py::test_calibrate_device_add_writes_the_effect_its_verdict_and_a_procedure_adds_too",  # noqa: E501
    "calibrate device --report": "test_device_badinput.py::test_cli_report_failure_leaves_no_record",
    "calibrate drift --out": "test_bad_input.py::test_check_and_calibrate_system_give_one_verdict",
    "calibrate drift --prior": "test_bad_input.py::test_check_and_calibrate_system_give_one_verdict",
    "calibrate lever --out": "test_lever.py::test_cli_calibrate_lever_all_arms",
    "calibrate lever --prior": "test_lever.py::test_cli_calibrate_lever_all_arms",
    "calibrate poses --columns": "test_poses.py::test_cli_writes_the_record_holds_and_plot",
    "calibrate poses --out": "test_poses.py::test_cli_writes_the_record_holds_and_plot",
    "calibrate poses --units": "test_poses.py::test_cli_writes_the_record_holds_and_plot",
    "calibrate poses --zero": "test_poses.py::test_cli_writes_the_record_holds_and_plot",
    "calibrate system --out": "test_bad_input.py::test_check_and_calibrate_system_give_one_verdict",
    "calibrate system --prior": "test_bad_input.py::test_check_and_calibrate_system_give_one_verdict",
    "campaign --no-plot": "test_campaign.py::test_distributed_scheduler_and_worker_give_the_local_table_and_resume",
    "campaign --out": "test_campaign.py::test_distributed_scheduler_and_worker_give_the_local_table_and_resume",
    "campaign --workers": "test_campaign.py::test_distributed_scheduler_and_worker_give_the_local_table_and_resume",
    "check --json": "test_cli.py::test_check_json_output",
    "check --trust": "test_report.py::test_signed_certificate_verifies_and_one_changed_byte_fails_with_the_reason",
    "design --target": "test_design.py::test_design_cli",
    "diagnose --add": "test_diagnose_library.py::test_device_document_round_trips",
    "diagnose --bias-instability": "test_diagnose_library.py::test_library_result_is_what_the_command_prints",
    "diagnose --bin": "test_discovery_cli.py::test_diagnose_system_record",
    "diagnose --json": "test_diagnose_library.py::test_library_result_is_what_the_command_prints",
    "diagnose --plots": "test_discovery_cli.py::test_diagnose_text_and_plots",
    "diagnose --random-walk": "test_diagnose_library.py::test_library_result_is_what_the_command_prints",
    "diagnose --record": "test_bad_input.py::test_two_second_dwells_give_a_flagged_result_not_a_traceback",
    "diagnose --stage": "test_report.py::test_pipeline_certificate_shows_the_fits_the_calibration_printed",
    "history --add": "test_recal_resume.py::test_an_interrupted_recal_resumed_as_the_console_says_files_exactly_one_record",
    "history --at": "test_history_store.py::test_fleet_which_units_are_due_and_which_drift",
    "history --drifted": "test_history_store.py::test_fleet_which_units_are_due_and_which_drift",
    "history --due": "test_history_store.py::test_fleet_which_units_are_due_and_which_drift",
    "history --fleet": "test_history_store.py::test_fleet_which_units_are_due_and_which_drift",
    "history --json": "test_history_store.py::test_fleet_which_units_are_due_and_which_drift",
    "history --plot": "test_history.py::test_two_records_a_minute_apart_state_no_drift",
    "history --store": "test_history.py::test_two_records_a_minute_apart_state_no_drift",
    "noise --json": "test_noise_cli.py::test_noise_command_writes_the_model_into_a_record_and_plots",
    "noise --out": "test_noise_cli.py::test_noise_command_writes_the_model_into_a_record_and_plots",
    "noise --plot": "test_noise_cli.py::test_noise_command_writes_the_model_into_a_record_and_plots",
    "noise --record": "test_noise_cli.py::test_noise_command_writes_the_model_into_a_record_and_plots",
    "protocol-check --envelope": "test_protocol_check.py::test_serve_sim_conforms",
    "recal --driver": "test_recal_resume.py::test_an_interrupted_recal_resumed_as_the_console_says_files_exactly_one_record",
    "recal --estimate": "test_truth.py::test_recal_history_and_certificate_agree_on_every_change_flag",
    "recal --json": "test_truth.py::test_recal_writes_one_record_in_force_whose_certificate_shows_it",
    "recal --out": "test_recal_resume.py::test_an_interrupted_recal_resumed_as_the_console_says_files_exactly_one_record",
    "recal --quiet": "test_truth.py::test_recal_writes_one_record_in_force_whose_certificate_shows_it",
    "recal --resume": "test_recal_resume.py::test_recal_resume_of_a_plain_run_names_the_right_command",
    "recal --seed": "test_recal_resume.py::test_an_interrupted_recal_resumed_as_the_console_says_files_exactly_one_record",
    "recal --set": "test_recal_resume.py::test_an_interrupted_recal_resumed_as_the_console_says_files_exactly_one_record",
    "recal --store": "test_recal_resume.py::test_an_interrupted_recal_resumed_as_the_console_says_files_exactly_one_record",
    "recal --unit": "test_recal_resume.py::test_an_interrupted_recal_resumed_as_the_console_says_files_exactly_one_record",
    "recal --yes": "test_recal_resume.py::test_recal_resume_of_a_plain_run_names_the_right_command",
    "report --data": "test_report.py::test_full_report_pages_and_required_fields",
    "report --discovery": "test_report.py::test_pipeline_certificate_shows_the_fits_the_calibration_printed",
    "report --operator": "test_report.py::test_signed_certificate_verifies_and_one_changed_byte_fails_with_the_reason",
    "report --out": "test_report.py::test_full_report_pages_and_required_fields",
    "report --previous": "test_report.py::test_full_report_pages_and_required_fields",
    "report --procedure": "test_report.py::test_full_report_pages_and_required_fields",
    "run --driver": "test_bad_input.py::test_resume_verifies_every_input_it_reads_again",
    "run --json": "test_runner_console.py::test_run_cli_prints_the_certificates_conformity_and_a_finished_run_is_left_alone",
    "run --out": "test_bad_input.py::test_resume_verifies_every_input_it_reads_again",
    "run --prior": "test_run_network_system.py::test_kill_9_in_the_record_over_tcp_then_resume_gives_identical_data",
    "run --quiet": "test_recal_resume.py::test_recal_resume_of_a_plain_run_names_the_right_command",
    "run --re-estimate": "test_runner_console.py::test_run_cli_prints_the_certificates_conformity_and_a_finished_run_is_left_alone",
    "run --resume": "test_bad_input.py::test_resume_verifies_every_input_it_reads_again",
    "run --seed": "test_bad_input.py::test_resume_verifies_every_input_it_reads_again",
    "run --set": "test_bad_input.py::test_resume_verifies_every_input_it_reads_again",
    "run --truth": "test_run_truth.py::test_run_with_a_known_truth_keeps_it_and_calibrate_drift_recovers_its_drift",
    "run --unit": "test_bad_input.py::test_resume_verifies_every_input_it_reads_again",
    "run --yes": "test_bad_input.py::test_resume_verifies_every_input_it_reads_again",
    "simulate --duration": "test_cli.py::test_simulate_system_streams_a_valid_record",
    "simulate --dwell": "test_cli.py::test_simulate_device_writes_data_and_truth",
    "simulate --json": "test_cli.py::test_simulate_list_effects",
    "simulate --list-effects": "test_cli.py::test_simulate_list_effects",
    "simulate --list-worlds": "test_worlds.py::test_cli_world_and_list",
    "simulate --no-iteration": "test_cli.py::test_simulate_device_writes_data_and_truth",
    "simulate --out": "test_cli.py::test_simulate_device_writes_data_and_truth",
    "simulate --procedure": "test_cli.py::test_simulate_device_writes_data_and_truth",
    "simulate --rate": "test_cli.py::test_simulate_system_streams_a_valid_record",
    "simulate --seed": "test_cli.py::test_simulate_system_streams_a_valid_record",
    "simulate --settle": "test_cli.py::test_simulate_device_writes_data_and_truth",
    "simulate --truth": "test_noise_cli.py::test_noise_from_a_static_system_record_recovers_the_simulated_terms",
    "simulate --world": "test_worlds.py::test_cli_world_and_list",
    "recal --timeout": "test_cli_options_more.py::test_recal_link_failures_and_timeout_over_tcp",
    "recal --link-failures": "test_cli_options_more.py::test_recal_link_failures_and_timeout_over_tcp",
    "run --new-calibration": "test_cli_options_more.py::test_run_new_calibration_starts_its_own",
    "run --timeout": "test_cli_options_more.py::test_run_link_failures_and_timeout_over_tcp",
    "run --link-failures": "test_cli_options_more.py::test_run_link_failures_and_timeout_over_tcp",
    "recal --re-estimate": "test_cli_options_more.py::test_recal_options",
    "recal --new-calibration": "test_cli_options_more.py::test_recal_options",
    "recal --retries": "test_cli_options_more.py::test_recal_options",
    "recal --chunk": "test_cli_options_more.py::test_recal_options",
    "recal --hidden": "test_cli_options_more.py::test_recal_options",
    "recal --truth": "test_cli_options_more.py::test_recal_options",
    "recal --prior": "test_cli_options_more.py::test_recal_options",
    "protocol-check --quiet": "test_protocol_check.py::test_protocol_check_options_duration_timeout_json_quiet",
    "protocol-check --json": "test_protocol_check.py::test_protocol_check_options_duration_timeout_json_quiet",
    "protocol-check --timeout": "test_protocol_check.py::test_protocol_check_options_duration_timeout_json_quiet",
    "protocol-check --duration": "test_protocol_check.py::test_protocol_check_options_duration_timeout_json_quiet",
    "run --store": "test_cli_options_more.py::test_run_chunk_retries_timeout_and_store",
    "run --retries": "test_cli_options_more.py::test_run_chunk_retries_timeout_and_store",
    "run --chunk": "test_cli_options_more.py::test_run_chunk_retries_timeout_and_store",
    "simulate --installed": "test_cli_options_more.py::test_simulate_format_and_installed",
    "simulate --format": "test_cli_options_more.py::test_simulate_format_and_installed",
    "diagnose --noise": "test_cli_options_more.py::test_diagnose_alpha_top_and_noise",
    "diagnose --top": "test_cli_options_more.py::test_diagnose_alpha_top_and_noise",
    "diagnose --alpha": "test_cli_options_more.py::test_diagnose_alpha_top_and_noise",
    "calibrate lever --quiet": "test_lever.py::test_cli_calibrate_lever_options",
    "calibrate lever --set": "test_lever.py::test_cli_calibrate_lever_options",
    "calibrate lever --new-calibration": "test_lever.py::test_cli_calibrate_lever_options",
    "calibrate lever --window": "test_lever.py::test_cli_calibrate_lever_options",
    "calibrate lever --no-asynchrony": "test_lever.py::test_cli_calibrate_lever_options",
    "calibrate thermal --quiet": "test_cli_options_stages.py::test_calibrate_thermal_options",
    "calibrate thermal --set": "test_cli_options_stages.py::test_calibrate_thermal_options",
    "calibrate thermal --new-calibration": "test_cli_options_stages.py::test_calibrate_thermal_options",
    "calibrate thermal --json": "test_cli_options_stages.py::test_calibrate_thermal_options",
    "calibrate drift --quiet": "test_cli_options_stages.py::test_calibrate_drift_options",
    "calibrate drift --set": "test_cli_options_stages.py::test_calibrate_drift_options",
    "calibrate drift --new-calibration": "test_cli_options_stages.py::test_calibrate_drift_options",
    "calibrate drift --one-position": "test_cli_options_stages.py::test_calibrate_drift_options",
    "calibrate drift --json": "test_cli_options_stages.py::test_calibrate_drift_options",
    "calibrate poses --quiet": "test_cli_options_poses.py::test_poses_noise_options_and_quiet",
    "calibrate poses --random-walk": "test_cli_options_poses.py::test_poses_noise_options_and_quiet",
    "calibrate poses --bias-instability": "test_cli_options_poses.py::test_poses_noise_options_and_quiet",
    "calibrate poses --noise": "test_cli_options_poses.py::test_poses_noise_options_and_quiet",
    "calibrate poses --holds": "test_cli_options_poses.py::test_poses_detection_options_and_edited_holds",
    "calibrate poses --min-hold": "test_cli_options_poses.py::test_poses_detection_options_and_edited_holds",
    "calibrate poses --false-split": "test_cli_options_poses.py::test_poses_detection_options_and_edited_holds",
    "calibrate poses --window": "test_cli_options_poses.py::test_poses_detection_options_and_edited_holds",
    "calibrate poses --detect-only": "test_cli_options_poses.py::test_poses_detection_options_and_edited_holds",
    "calibrate poses --rate": "test_cli_options_poses.py::test_poses_time_unit_and_rate_read_the_same_log",
    "calibrate poses --time-unit": "test_cli_options_poses.py::test_poses_time_unit_and_rate_read_the_same_log",
    "calibrate poses --range": "test_cli_options_poses.py::test_poses_gravity_serial_and_range",
    "calibrate poses --serial": "test_cli_options_poses.py::test_poses_gravity_serial_and_range",
    "calibrate poses --gravity": "test_cli_options_poses.py::test_poses_gravity_serial_and_range",
    "diagnose --allow-gaps": "test_cli_options_system.py::test_allow_gaps_lets_check_calibrate_and_diagnose_read_a_gapped_record",
    "check --allow-gaps": "test_cli_options_system.py::test_allow_gaps_lets_check_calibrate_and_diagnose_read_a_gapped_record",
    "calibrate system --allow-gaps": "test_cli_options_system.py::test_allow_gaps_lets_check_calibrate_and_diagnose_read_a_gapped_record",
    "calibrate system --noise": "test_cli_options_system.py::test_calibrate_system_gyro_drift_and_noise_options",
    "calibrate system --gyro-drift-uncertainty": "test_cli_options_system.py::test_calibrate_system_gyro_drift_and_noise_options",
    "calibrate system --gyro-drift": "test_cli_options_system.py::test_calibrate_system_gyro_drift_and_noise_options",
    "calibrate system --chunk-rows": "test_cli_options_system.py::test_calibrate_system_chunk_rows_do_not_change_the_result",
    "calibrate system --new-calibration": "test_cli_options_system.py::test_calibrate_system_model_options",
    "calibrate system --set": "test_cli_options_system.py::test_calibrate_system_model_options",
    "calibrate system --estimate-k2": "test_cli_options_system.py::test_calibrate_system_model_options",
    "calibrate system --no-loop-compensation": "test_cli_options_system.py::test_calibrate_system_model_options",
    "calibrate system --no-couplings": "test_cli_options_system.py::test_calibrate_system_model_options",
    "calibrate system --case-rotation-period": "test_cli_options_system.py::test_calibrate_system_model_options",
    "campaign --json": "test_cli_options_quiet.py::test_campaign_json_and_quiet",
    "campaign --quiet": "test_cli_options_quiet.py::test_campaign_json_and_quiet",
    "simulate --quiet": "test_cli_options_quiet.py::test_a_terminal_sees_the_bar_and_quiet_removes_it",
    "report --quiet": "test_cli_options_quiet.py::test_quiet_silences_the_command",
    "noise --quiet": "test_cli_options_quiet.py::test_quiet_silences_the_command",
    "history --quiet": "test_cli_options_quiet.py::test_quiet_silences_the_command",
    "diagnose --quiet": "test_cli_options_quiet.py::test_quiet_silences_the_command",
    "design --quiet": "test_cli_options_quiet.py::test_quiet_silences_the_command",
    "check --quiet": "test_cli_options_quiet.py::test_quiet_silences_the_command",
    "calibrate system --quiet": "test_cli_options_quiet.py::test_quiet_silences_the_command",
    "calibrate device --quiet": "test_cli_options_quiet.py::test_quiet_silences_the_command",
    "budget --quiet": "test_cli_options_quiet.py::test_quiet_silences_the_command",
    "design --grid": "test_cli_options_design.py::test_design_grid_chooses_positions_on_the_grid",
    "design --criterion": "test_cli_options_design.py::test_design_budget_and_criterion",
    "design --budget": "test_cli_options_design.py::test_design_budget_and_criterion",
    "design --sample-rate": "test_cli_options_design.py::test_design_match_bounds_out_and_name",
    "design --name": "test_cli_options_design.py::test_design_match_bounds_out_and_name",
    "design --out": "test_cli_options_design.py::test_design_match_bounds_out_and_name",
    "design --max-dwell": "test_cli_options_design.py::test_design_match_bounds_out_and_name",
    "design --min-dwell": "test_cli_options_design.py::test_design_match_bounds_out_and_name",
    "design --match": "test_cli_options_design.py::test_design_match_bounds_out_and_name",
    "design --fine": "test_cli_options_design.py::test_design_plan_options_change_the_evaluated_plan",
    "design --passes": "test_cli_options_design.py::test_design_plan_options_change_the_evaluated_plan",
    "design --json": "test_cli_options_design.py::test_design_noise_options_set_the_noise_model",
    "design --noise": "test_cli_options_design.py::test_design_noise_options_set_the_noise_model",
    "design --quantization": "test_cli_options_design.py::test_design_noise_options_set_the_noise_model",
    "design --random-walk": "test_cli_options_design.py::test_design_noise_options_set_the_noise_model",
    "design --bias-instability": "test_cli_options_design.py::test_design_noise_options_set_the_noise_model",
    "design --white": "test_cli_options_design.py::test_design_noise_options_set_the_noise_model",
    "serve-sim --unit": "test_cli_options_servers.py::test_serve_sim_options_reach_the_platform",
    "serve-sim --truth": "test_cli_options_servers.py::test_serve_sim_options_reach_the_platform",
    "serve-sim --seed": "test_cli_options_servers.py::test_serve_sim_options_reach_the_platform",
    "serve-sim --realtime": "test_cli_options_servers.py::test_serve_sim_options_reach_the_platform",
    "serve-sim --rate": "test_cli_options_servers.py::test_serve_sim_options_reach_the_platform",
    "serve-sim --quiet": "test_cli_options_servers.py::test_serve_sim_options_reach_the_platform",
    "serve-sim --port": "test_cli_options_servers.py::test_serve_sim_options_reach_the_platform",
    "serve-sim --installed": "test_cli_options_servers.py::test_serve_sim_options_reach_the_platform",
    "serve-sim --connections": "test_cli_options_servers.py::test_serve_sim_options_reach_the_platform",
    "serve --token-file": "test_cli_options_servers.py::test_serve_options_reach_the_server",
    "serve --store": "test_cli_options_servers.py::test_serve_options_reach_the_server",
    "serve --secure-cookie": "test_cli_options_servers.py::test_serve_options_reach_the_server",
    "serve --runs": "test_cli_options_servers.py::test_serve_options_reach_the_server",
    "serve --rate": "test_cli_options_servers.py::test_serve_options_reach_the_server",
    "serve --port": "test_cli_options_servers.py::test_serve_options_reach_the_server",
    "serve --policy": "test_cli_options_servers.py::test_serve_options_reach_the_server",
    "serve --host": "test_cli_options_servers.py::test_serve_options_reach_the_server",
    "serve --burst": "test_cli_options_servers.py::test_serve_options_reach_the_server",
    "simulate --hidden": "test_worlds.py::test_cli_world_and_list",
    "run --hidden": "test_run_truth.py::test_hidden_effects_are_simulated_and_kept_and_a_resume_simulates_the_same_world",
    "report --sign-cert": "test_report.py::test_signed_certificate_verifies_and_one_changed_byte_fails_with_the_reason",
    "report --sign": "test_report.py::test_signed_certificate_verifies_and_one_changed_byte_fails_with_the_reason",
    "history --max-age": "test_history.py::test_cli_history_and_recal_with_an_estimate",
    "campaign --scheduler": "test_campaign.py::test_distributed_scheduler_and_worker_give_the_local_table_and_resume",
    "calibrate thermal --prior": "test_thermal_sensitivity.py::test_cli_carries_the_sensitivities_in_the_record",
    "calibrate thermal --out": "test_thermal_sensitivity.py::test_cli_carries_the_sensitivities_in_the_record",
    "calibrate system --cross-coupling": "test_systematic_cross_coupling.py::test_cli_cross_coupling",
    "calibrate system --systematic": "test_systematic.py::test_cli_updates_the_record",
    "calibrate system --thermal-prior": "test_system_cli.py::test_cli_thermal_prior_and_json_thermal",
    "calibrate system --plot": "test_system_cli.py::test_cli_plot",
    "calibrate system --json": "test_system_cli.py::test_cli_json",
    "calibrate system --random-walk": "test_system_cli.py::test_cli_noise_model_in_and_out",
    "calibrate system --bias-instability": "test_system_cli.py::test_cli_noise_model_in_and_out",
    "calibrate poses --write-holds": "test_poses.py::test_cli_writes_the_record_holds_and_plot",
    "calibrate poses --plot": "test_poses.py::test_cli_writes_the_record_holds_and_plot",
    "calibrate poses --json": "test_poses.py::test_cli_writes_the_record_holds_and_plot",
    "calibrate poses --diagnose": "test_poses.py::test_diagnose_finds_a_hidden_effect_in_the_holds_and_add_carries_it",
    "calibrate poses --add": "test_poses.py::test_diagnose_finds_a_hidden_effect_in_the_holds_and_add_carries_it",
    "calibrate lever --json": "test_lever.py::test_cli_calibrate_lever_all_arms",
    "calibrate lever --all-arms": "test_lever.py::test_cli_calibrate_lever_all_arms",
    "calibrate device --verbose": "test_device_simulator.py::test_cli_calibrates_simulated_files_and_writes_a_record",
}
#: Options no test runs successfully yet (only shrinks; issue 31 left 139 of 259, then 1 of 256: the servers take no --json).
NOT_YET_RUN: frozenset[str] = frozenset()


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
def _test_sources(file: str) -> dict[str, tuple[str, frozenset[str]]]:
    """Module-level functions of a test file: their source and the names of the module's functions they call."""
    source = (TESTS / file).read_text(encoding="utf-8")
    functions = {n.name: n for n in ast.parse(source).body if isinstance(n, ast.FunctionDef)}

    def calls(node: ast.FunctionDef) -> frozenset[str]:
        names = (c.func.id for c in ast.walk(node) if isinstance(c, ast.Call) and isinstance(c.func, ast.Name))
        return frozenset(name for name in names if name in functions)

    return {name: (ast.get_source_segment(source, node) or "", calls(node)) for name, node in functions.items()}


@pytest.mark.parametrize("option", sorted(RUN_BY))
def test_the_named_test_runs_the_option(option: str) -> None:
    """The test exists, and it or a helper of its file that it calls spells the option and checks an exit status of 0."""
    file, _, name = RUN_BY[option].partition("::")
    sources = _test_sources(file)
    assert name in sources, f"{RUN_BY[option]} does not exist"
    source, called = sources[name]
    spelling = option.rsplit(" ", 1)[1]
    texts = [source, *(sources[helper][0] for helper in called)]
    spelled, checked = any(f'"{spelling}"' in text for text in texts), any("== 0" in text for text in texts)
    assert spelled and checked, f"{RUN_BY[option]} does not run {option} successfully"


def test_hypothesis_is_derandomized_suite_wide() -> None:
    """tests/conftest.py loads a derandomized profile: every hypothesis test sees the same cases every run."""
    from hypothesis import settings

    assert settings.default.derandomize and settings.default.database is None


# --------------------------------------------------------------------------- options run here (issue 31), effect asserted
@pytest.fixture(scope="module")
def ws(fuzz_workspace):
    return fuzz_workspace  # tests/conftest.py: built once per process


def test_report_identification_statement_and_technical_options(ws, tmp_path):
    technical = tmp_path / "evidence.pdf"
    argv = ["report", ws.record, "--laboratory", "Lab L", "--customer", "Customer C", "--operator", "Operator O", "--report-id", "R-31",
            "--no-statement", "--technical", technical, "--out", tmp_path / "r.pdf", "--json"]  # fmt: skip
    status, out, _ = run_cli(argv)
    assert status == 0
    document = json.loads(out)  # --json: the summary on stdout
    assert document["report_id"] == "R-31"  # --report-id
    assert document["verdict"] == "NO STATEMENT"  # --no-statement
    assert document["technical_report"]["path"] == str(technical) and technical.stat().st_size > 10_000  # --technical
    assert document["draft"] == []  # --laboratory, --customer, --operator: all three given, not a draft
    status, out, _ = run_cli(["report", ws.record, "--out", tmp_path / "d.pdf", "--json"])
    assert status == 0 and json.loads(out)["draft"] and json.loads(out)["report_id"] != "R-31"


def test_noise_confidence_sets_the_interval(ws):
    widths = {}
    for confidence in ("0.7", "0.99"):
        status, out, _ = run_cli(["noise", ws.system_h5, "--confidence", confidence, "--json"])
        assert status == 0
        model = json.loads(out)["noise_model"]
        assert model["confidence"] == float(confidence)
        white = model["axes"]["x"]["white"]
        widths[confidence] = white["upper"] - white["lower"]
    assert 0 < widths["0.7"] < widths["0.99"]


def test_history_verify_finds_a_changed_record(ws, tmp_path):
    store = tmp_path / "store"
    status, _, _ = run_cli(["history", ws.serial, "--store", store, "--add", ws.record])
    assert status == 0
    status, _, _ = run_cli(["history", ws.serial, "--store", store, "--verify"])
    assert status == 0  # every filed record matches its SHA-256
    filed = [p for p in store.rglob("*.json") if p.is_file() and ws.serial in str(p)]
    assert filed
    filed[0].write_text(filed[0].read_text().replace("stableins test", "stableins TEST"))
    status, _, _ = run_cli(["history", ws.serial, "--store", store, "--verify"])
    assert status != 0


def test_calibrate_device_options(ws, tmp_path):
    first, second = tmp_path / "a.json", tmp_path / "b.json"
    argv = ["calibrate", "device", ws.device_csv, "--coarse-procedure", "device-coarse", "--coarse-linear", "--set", "laboratory=Lab L",
            "--add", "Kcc_xxy", "--keep-unsupported", "--alpha", "0.01", "--out", first, "--json"]  # fmt: skip
    status, out, _ = run_cli(argv)
    assert status == 0
    record = json.loads(first.read_text())
    settings = record["stages"][-1]["settings"]
    assert settings["coarse_procedure"] == "device-coarse" and settings["coarse_nonlinear"] is False  # --coarse-procedure, --coarse-linear
    assert {"key": "laboratory", "value": "Lab L", "unit": ""} in record["calibration"]["entries"]  # --set
    assert "Kcc_xxy" in [p["id"] for p in record["parameters"]]  # --add, kept by --keep-unsupported whatever its test says
    assert json.loads(out)["discovery"]["alpha"] == 0.01  # --alpha
    status, _, _ = run_cli(["calibrate", "device", ws.device_csv, "--noise", first, "--allow-missing", "--out", second])
    assert status == 0
    again = json.loads(second.read_text())["stages"][-1]["settings"]
    assert again["allow_missing"] is True and again["coarse_nonlinear"] is True  # --allow-missing; the default nonlinear coarse stage
    assert again["noise_model"]["axes"] == settings["noise_model"]["axes"]  # --noise: the model of that record, not re-measured
