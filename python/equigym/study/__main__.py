"""``python -m equigym.study``: the command line (:mod:`equigym.study.cli`)."""

from equigym.study.cli import main

main()
