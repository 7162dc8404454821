"""Platform drivers: one interface to the simulated, networked or replayed platform."""
