"""``python -m voxflex`` is the ``voxflex`` command."""

from voxflex.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
