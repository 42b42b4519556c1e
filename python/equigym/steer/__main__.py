"""``python -m equigym.steer``: the command line (:mod:`equigym.steer.cli`)."""

from equigym.steer.cli import main

main()
