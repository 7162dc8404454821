"""Estimators: coarse and fine device-level stages, system-level stage; all return frozen results."""
