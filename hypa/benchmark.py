"""``python -m hypa.benchmark``: the command is :mod:`hypa.commands.benchmark`
(every command lives in :mod:`hypa.commands`)."""

from hypa.commands.benchmark import main

if __name__ == "__main__":
    main()
