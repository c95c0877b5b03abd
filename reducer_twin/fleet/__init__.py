"""The fleet: every reducer's life across bags in one store, verdicts, and engines."""
