"""``hypa_run``: a hypa command run in the test's own process, in place of
``subprocess.run([sys.executable, "-m", "hypa", *args], cwd=..., env=..., capture_output=True, text=True)``.

Why in-process: a child interpreter imports torch, Lightning and Hydra (5-8 s on a test machine) before it
does a CLI test's tiny job, and most CLI tests check what the command writes, prints and exits with, not
the process. ``hypa_run`` calls :func:`hypa.commands.cli.main` as ``python -m hypa`` would and returns the
same :class:`subprocess.CompletedProcess`: the exit status (``sys.exit``'s code, 0 for none; an uncaught
exception prints its traceback and is 1, as the interpreter does), stdout and stderr as text.

The output is caught at the file descriptors 1 and 2 (with ``sys.stdout``/``sys.stderr`` writing to them):
what Python prints, Hydra's and Lightning's logging, C libraries and the commands a command starts
(``hypa benchmark``'s trainings) come back in the order they were written, as from a child process.

Restored afterwards, so that the next test (or the next ``hypa_run``) finds the process as it was: the
working directory (the command runs in ``cwd``), ``os.environ`` (``env``, a whole environment as the
tests pass ``{**os.environ, ...}``, is the command's; the commands set ``HYPA_FULL_ERROR``,
``HYDRA_FULL_ERROR``, ``PL_GLOBAL_SEED``...), ``sys.argv``, ``sys.path`` (``cwd`` and ``PYTHONPATH``
are on it while the command runs, as for ``python -m``), the user's modules in ``sys.modules`` (the
command imports its own, as a child would: a later test's ``dc_motor.py`` is its own),
``__main__.__spec__`` (``cli.main`` sets it), torch's threads (``hypa train`` sets them), deterministic
algorithms and default dtype, the random generators of ``random``, numpy and torch, every logger's
level, handlers, propagation and ``disabled`` (Hydra configures the root logger's; pytest's log capture
keeps working; the handlers added, the run's log file among them, are closed), the warning filters (a
fresh interpreter's while the command runs: its warnings are on stderr, not in pytest's summary), the
SIGINT handler and signal mask, the figures opened, and Hydra's global state (``GlobalHydra``,
``HydraConfig``). ``timeout`` is accepted and ignored: nothing stops a call in this process
(pytest-timeout still ends the test).

Not the same as a child, so these stay real subprocesses (``subprocess.run([sys.executable, "-m",
"hypa", ...])``): Ctrl-C (SIGINT, exit status 130), two commands at once (a held run folder), ddp and
other multi-process training, Hydra sweeps through a launcher (``-m``), the spellings ``python -m
hypa.train`` and ``python -m hypa``'s own dispatch and the console script ``hypa``, what happens at
import time or depends on the environment the interpreter starts with, a process with limits of its
own (``preexec_fn``: a full disk), a new session or a terminal, and tests/docs and the notebooks. Each
command keeps at least one test through a real process (tests/commands/test_hypa_run.py says where).
"""

from __future__ import annotations

import contextlib
import functools
import io
import logging
import os
import random
import signal
import subprocess
import sys
import tempfile
import traceback
import warnings
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

from conftest import ROOT


def hypa_run(args: Sequence[str], cwd: Path = ROOT, env: Mapping[str, str] | None = None,
             timeout: float | None = None) -> subprocess.CompletedProcess[str]:
    """``hypa ARGS`` (``args``: the command and its arguments) run in this process in ``cwd`` with the
    environment ``env`` (this process's when None): its exit status, stdout and stderr (``timeout``:
    ignored, see the module docstring)."""
    from hypa.commands import cli

    argv = [str(a) for a in args]
    with _process_state(cwd, env), _output() as output:
        try:
            status = cli.main(argv)
        except SystemExit as exit_:
            status = _exit_status(exit_.code)
        except Exception:  # noqa: BLE001 - a bug: the interpreter prints the traceback and exits 1
            traceback.print_exc()
            status = 1
    return subprocess.CompletedProcess(["hypa", *argv], status, *output)


def _exit_status(code: object) -> int:
    """The exit status of ``sys.exit(code)``, as the interpreter gives it (a message: printed, 1)."""
    if code is None or isinstance(code, int):
        return code or 0
    print(code, file=sys.stderr)
    return 1


@contextlib.contextmanager
def _output() -> Iterator[list[str]]:
    """File descriptors 1 and 2 into temporary files, ``sys.stdout``/``sys.stderr`` writing to them; yields
    a list that holds [stdout, stderr] once the block ends."""
    caught: list[str] = []
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err, contextlib.ExitStack() as stack:
        for stream in (sys.stdout, sys.stderr, sys.__stdout__, sys.__stderr__):
            with contextlib.suppress(Exception):
                stream.flush()
        saved = [os.dup(1), os.dup(2)]
        os.dup2(out.fileno(), 1)
        os.dup2(err.fileno(), 2)
        try:
            streams = [io.TextIOWrapper(io.FileIO(os.dup(fd), "w"), encoding="utf-8", write_through=True)
                       for fd in (1, 2)]
            for stream in streams:
                stack.callback(stream.close)
            stack.enter_context(contextlib.redirect_stdout(streams[0]))
            stack.enter_context(contextlib.redirect_stderr(streams[1]))
            yield caught
            stack.close()
        finally:
            for fd, copy in zip((1, 2), saved):
                os.dup2(copy, fd)
                os.close(copy)
        for file in (out, err):
            file.seek(0)
            caught.append(file.read().decode("utf-8", errors="replace"))


@contextlib.contextmanager
def _process_state(cwd: Path, env: Mapping[str, str] | None) -> Iterator[None]:
    """Run the block in ``cwd`` with ``env``, and restore what a command changes (the module docstring)."""
    import numpy as np
    import torch
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.hydra_config import HydraConfig

    environ, path, argv, folder = dict(os.environ), list(sys.path), list(sys.argv), os.getcwd()
    users = {name: module for name, module in list(sys.modules.items()) if _users(name, module)}
    for name in users:  # what the command imports from the user's folders, it imports afresh
        del sys.modules[name]
    main = sys.modules["__main__"]
    spec = main.__spec__
    torch_state = (torch.get_num_threads(), torch.are_deterministic_algorithms_enabled(),
                   torch.is_deterministic_algorithms_warn_only_enabled(), torch.get_default_dtype())
    generators = (random.getstate(), np.random.get_state(), torch.random.get_rng_state())
    loggers = _loggers()
    sigint = signal.getsignal(signal.SIGINT)
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, []) if hasattr(signal, "pthread_sigmask") else None
    figures = _figures()
    try:
        with warnings.catch_warnings():
            _fresh_warnings()
            if env is not None:
                os.environ.clear()
                os.environ.update(env)
            os.chdir(cwd)
            sys.path[:0] = [str(Path(cwd).resolve()), *filter(None, os.environ.get("PYTHONPATH", "").split(os.pathsep))]
            import importlib

            importlib.invalidate_caches()  # a module the test has just written is found
            yield
    finally:
        GlobalHydra.instance().clear()
        HydraConfig.instance().cfg = None  # type: ignore[assignment]
        os.chdir(folder)
        os.environ.clear()
        os.environ.update(environ)
        sys.path[:], sys.argv[:] = path, argv
        for name in [name for name, module in list(sys.modules.items()) if _users(name, module)]:
            del sys.modules[name]
        sys.modules.update(users)
        main.__spec__ = spec
        threads, deterministic, warn_only, dtype = torch_state
        torch.set_num_threads(threads)
        torch.use_deterministic_algorithms(deterministic, warn_only=warn_only)
        torch.set_default_dtype(dtype)
        random.setstate(generators[0])
        np.random.set_state(generators[1])
        torch.random.set_rng_state(generators[2])
        _restore_loggers(loggers)
        signal.signal(signal.SIGINT, sigint)
        if mask is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        _close_figures(figures)


def _fresh_warnings() -> None:
    """The warning filters of an interpreter started without ``-W``, and warnings printed on stderr, as
    from a child (pytest's filters and its record of warnings are the test's own)."""
    warnings.resetwarnings()
    for category in (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning):
        warnings.filterwarnings("ignore", category=category)
    warnings.filterwarnings("default", category=DeprecationWarning, module="__main__")
    warnings.showwarning = _on_stderr  # pytest records warnings below showwarning: this one prints them


def _on_stderr(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning as the interpreter prints it, on the command's stderr."""
    sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))


_KEPT = tuple(Path(p).resolve() for p in {sys.prefix, sys.base_prefix, ROOT / "hypa", ROOT / "tests"})


def _users(name: str, module: object) -> bool:
    """A module from outside the interpreter's packages, hypa and the tests: a user's system (the example's
    ``dc_motor``, a test's ``mynets.py``), which a command run as a child imports from its own ``sys.path``."""
    origin = getattr(module, "__file__", None) or next(iter(getattr(module, "__path__", None) or ()), None)
    return name != "__main__" and origin is not None and _outside(str(origin))


@functools.cache
def _outside(origin: str) -> bool:
    return not any(Path(origin).resolve().is_relative_to(kept) for kept in _KEPT)


_Loggers = dict[str, tuple[logging.Logger, int, list[logging.Handler], bool, bool]]


def _loggers() -> tuple[_Loggers, int]:
    """Every logger's level, handlers, propagation and ``disabled``, and ``logging.disable``'s level."""
    manager = logging.root.manager
    loggers = [logging.root, *(x for x in manager.loggerDict.values() if isinstance(x, logging.Logger))]
    return {x.name: (x, x.level, list(x.handlers), x.propagate, x.disabled) for x in loggers}, manager.disable


def _restore_loggers(saved: tuple[_Loggers, int]) -> None:
    """The loggers as :func:`_loggers` found them; a handler added since is closed (a run's log file)."""
    states, disabled = saved
    before = {id(h) for _, _, handlers, _, _ in states.values() for h in handlers}
    now, _ = _loggers()
    for name, (logger, *_rest) in now.items():
        for handler in logger.handlers:
            if id(handler) not in before:
                handler.close()
        if name in states:
            _, level, handlers, propagate, off = states[name]
            logger.setLevel(level)
            logger.handlers[:] = handlers
            logger.propagate, logger.disabled = propagate, off
        else:
            logger.handlers[:] = [h for h in logger.handlers if id(h) in before]
    logging.disable(disabled)


def _figures() -> set[int]:
    pyplot = sys.modules.get("matplotlib.pyplot")
    return set(pyplot.get_fignums()) if pyplot else set()


def _close_figures(before: set[int]) -> None:
    pyplot = sys.modules.get("matplotlib.pyplot")
    for number in set(pyplot.get_fignums()) - before if pyplot else ():
        pyplot.close(number)
