"""``python -m hypa.reproduce``: the command is :mod:`hypa.commands.reproduce`
(every command lives in :mod:`hypa.commands`)."""

from hypa.commands.reproduce import main

if __name__ == "__main__":
    main()
