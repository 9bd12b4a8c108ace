"""``python -m hypa.explain``: the command is :mod:`hypa.commands.explain`."""

from hypa.commands.explain import main

main()
