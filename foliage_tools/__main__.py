"""``python -m foliage_tools`` = the ``foliage`` command."""

from foliage_tools.cli.main import main

if __name__ == "__main__":
    main()
