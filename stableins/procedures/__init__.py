"""Calibration procedures: TOML definitions (``procedures/`` at the top level) and their execution."""
