"""Stages: read -> compute -> write, atomically. The CLI calls these; they do no parsing or printing."""
