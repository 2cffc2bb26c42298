"""Bus configuration models and the thin wrappers drivers use to talk to a bus."""
