"""``python -m voxflex`` is the ``voxflex`` command."""

from voxflex.cli import entry

if __name__ == "__main__":
    entry()
