"""``python -m hypa.train``: the command is :mod:`hypa.commands.train` (every command lives in :mod:`hypa.commands`)."""

from hypa.commands.train import main

if __name__ == "__main__":
    main()
