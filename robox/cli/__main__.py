"""`python -m robox.cli` runs robox-cli."""

from robox.cli import main

main()
