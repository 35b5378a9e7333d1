"""openemt.solve (see docs/architecture in README)."""
