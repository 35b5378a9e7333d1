"""openemt.bench (see docs/architecture in README)."""
