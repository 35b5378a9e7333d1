"""openemt.live (see docs/architecture in README)."""
