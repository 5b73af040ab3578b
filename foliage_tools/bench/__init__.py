"""Speed against error: metrics and the registry of methods ``foliage bench`` compares."""
