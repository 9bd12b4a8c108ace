"""``python -m hypa.export``: the command is :mod:`hypa.commands.export`."""

from hypa.commands.export import main

main()
