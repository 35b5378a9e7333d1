"""openemt.calibrate (see docs/architecture in README)."""
