"""openemt.report (see docs/architecture in README)."""
