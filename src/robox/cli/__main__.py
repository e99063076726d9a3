"""`python -m robox.cli` runs robox-cli."""

from robox.launch import main

main()
