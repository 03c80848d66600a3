"""`python -m demoforge`: the command line."""

from demoforge.cli import main

main()
