"""``python -m hypa.diagnose``: the command is :mod:`hypa.commands.diagnose`
(every command lives in :mod:`hypa.commands`)."""

from hypa.commands.diagnose import main

if __name__ == "__main__":
    main()
