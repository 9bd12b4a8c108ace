"""``python -m hypa.evaluate``: the command is :mod:`hypa.commands.evaluate`
(every command lives in :mod:`hypa.commands`)."""

from hypa.commands.evaluate import main

if __name__ == "__main__":
    main()
