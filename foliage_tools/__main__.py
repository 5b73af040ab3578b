"""``python -m foliage_tools`` = the ``foliage`` command."""

from foliage_tools import interrupts

interrupts.install_interrupts()  # first: a signal during the imports below is an interrupt too (exit 130)

from foliage_tools.cli.main import main  # noqa: E402

if __name__ == "__main__":
    main()
