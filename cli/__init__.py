"""The ``foliage`` command (installed as ``foliage_tools.cli``): parses, shows progress, maps errors to exit codes. No maths."""
