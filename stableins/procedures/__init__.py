"""Calibration procedures: definitions (TOML), step-by-step execution, the run journal."""
