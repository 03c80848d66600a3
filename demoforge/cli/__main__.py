"""`python -m demoforge.cli`: the command line."""

from demoforge.cli import main

main()
