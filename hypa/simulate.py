"""``python -m hypa.simulate``: the command is :mod:`hypa.commands.simulate`
(every command lives in :mod:`hypa.commands`)."""

from hypa.commands.simulate import main

if __name__ == "__main__":
    main()
