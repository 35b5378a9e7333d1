"""openemt.correct (see docs/architecture in README)."""
