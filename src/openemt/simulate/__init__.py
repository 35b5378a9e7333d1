"""openemt.simulate (see docs/architecture in README)."""
