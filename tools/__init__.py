"""Command-line tools: handbus, and the others as they land."""
