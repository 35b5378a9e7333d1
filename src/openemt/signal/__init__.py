"""openemt.signal (see docs/architecture in README)."""
