"""Model discovery: compare the model with the measurements, find the physical effect it misses, add it, carry it into the calibration."""
