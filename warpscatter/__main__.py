"""``python -m warpscatter``: the command-line application (the same as the ``warpscatter`` script)."""

from warpscatter.cli.entry import run

if __name__ == "__main__":
    run()
