"""One module per bench method; each registers itself with foliage_tools.bench.registry.register."""
