"""``python -m warpscatter``: the command-line application (the same as the ``warpscatter`` script)."""

from warpscatter.cli.main import main

if __name__ == "__main__":
    main()
