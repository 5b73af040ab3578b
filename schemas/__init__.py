"""Data files: codeless USD API schemas (usd/) and JSON report schemas (json/)."""
