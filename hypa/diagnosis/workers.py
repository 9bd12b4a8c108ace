"""A search round's gradient fits on several processes.

The candidates of a round are independent: each is a model of its own, fitted on the same
training windows. The workers are forked when the round starts, so they inherit the problem,
the windows and the round's fits (nothing is pickled on the way in); each owns some of the fits
for the whole round, advances them when told to and sends back only what the race needs (the
score, how far the fit got, its values). A fit's result does not depend on where it ran: its
batches come from its own seeded generator.

Used by :func:`hypa.diagnosis.race.evaluate_round` when ``Problem.workers`` > 1 and the
platform can fork; otherwise the round runs in the calling process.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import traceback
from collections.abc import Callable, Iterator, Mapping, Sequence
from multiprocessing.connection import wait
from typing import Any

import torch

NONLINEAR_COST = 6.0  # a nonlinear fit (simulated step by step) costs about this many linear ones


def default_workers() -> int:
    """One per core this process may use, at most 4 (a round has about ten candidates)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(4, cores))


def can_fork() -> bool:
    return "fork" in multiprocessing.get_all_start_methods()


class Workers:
    """Forked processes that advance a round's runners (``race._Runner``), one task at a time.

    :meth:`run` hands out the tasks of a rung (advance runner i to ``share`` of its steps and
    score it), the most expensive first, each to the next idle worker; a fit that is not done
    stays with the worker that holds its state. Between the replies the calling process runs
    its own small jobs (the offsets). Use as a context manager: the workers end with the round.
    """

    def __init__(self, runners: Sequence[Any], count: int, val: Any) -> None:
        self.runners, self.owner = runners, {}
        context = multiprocessing.get_context("fork")
        self.pipes, self.processes = [], []
        with _sigint_held():  # a Ctrl-C meanwhile reaches this process once the workers ignore it
            for _ in range(count):
                mine, theirs = context.Pipe()
                process = context.Process(target=_serve, args=(theirs, runners, val), daemon=True)
                process.start()
                theirs.close()
                self.pipes.append(mine)
                self.processes.append(process)

    def run(self, shares: Mapping[int, float], jobs: Sequence[Callable[[], None]] = ()) -> None:
        """Advance runner i to ``shares[i]`` of its steps on the workers; run ``jobs`` meanwhile."""
        tasks = sorted(shares, key=lambda i: -_cost(self.runners[i], shares[i]))
        jobs, idle, busy = list(jobs), list(range(len(self.pipes))), {}
        while tasks or busy:
            for w in list(idle):
                task = next((i for i in tasks if self.owner.get(i, w) == w), None)
                if task is not None:
                    tasks.remove(task)
                    self.owner[task] = w
                    self.pipes[w].send((task, shares[task]))
                    idle.remove(w)
                    busy[self.pipes[w]] = w
            if jobs:
                jobs.pop(0)()
            for pipe in wait(list(busy), timeout=0 if jobs else None):
                w = busy.pop(pipe)
                self._receive(w)
                idle.append(w)
        for job in jobs:
            job()

    def _receive(self, w: int) -> None:
        try:
            kind, payload = self.pipes[w].recv()
        except EOFError as error:
            raise RuntimeError(f"a diagnosis worker (pid {self.processes[w].pid}) ended unexpectedly") from error
        if kind == "failed":
            raise RuntimeError(f"a diagnosis worker failed:\n{payload}")
        i, state = payload
        runner = self.runners[i]
        runner.score, runner.previous, runner.error, runner.seconds = (
            state["score"], state["previous"], state["error"], state["seconds"])
        runner.fit.done, runner.values = state["done"], state["values"]
        runner.fit.diverged, runner.fit.timed_out = state["diverged"], state["timed_out"]
        runner.fit.converged, runner.promise = state["converged"], state["promise"]

    def __enter__(self) -> Workers:  # noqa: PYI034 -- never subclassed; typing.Self needs 3.11
        return self

    def __exit__(self, kind: type[BaseException] | None, *exc: object) -> None:
        if kind is not None:  # Ctrl-C or an error in the round: the workers' fits are not wanted any more
            for process in self.processes:
                process.kill()
        for pipe in self.pipes:
            with contextlib.suppress(BrokenPipeError, OSError):
                pipe.send(None)
            pipe.close()
        for process in self.processes:
            process.join(timeout=5)
            if process.is_alive():
                process.kill()
                process.join(timeout=5)


@contextlib.contextmanager
def _sigint_held() -> Iterator[None]:
    """SIGINT blocked (held pending, not lost) in this thread while the workers are forked: a worker
    inherits the mask and ignores the signal before it unblocks it, so Ctrl-C never interrupts one
    before it can ignore it; this process gets a held Ctrl-C when the block ends."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def _cost(runner: Any, share: float) -> float:
    """The steps left to ``share``, in units of a linear fit's step (a screen: one step)."""
    steps = max(1.0 if share == 0 else 0.0, share * runner.fit.total - runner.fit.done)
    return steps * (NONLINEAR_COST if runner.fit.nonlinear else 1.0)


def _serve(pipe, runners: Sequence[Any], val: Any) -> None:
    """A worker: advance the runner it is told to, reply with its state, until told None.

    It ignores Ctrl-C (SIGINT goes to the whole process group): the parent process stops the
    round and ends the workers, and says so in one line, instead of a traceback from every worker."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # held while forking (_sigint_held)
    torch.set_num_threads(1)
    try:
        _serve_tasks(pipe, runners, val)
    finally:  # a worker ends by os._exit: no finalizer removes what it extracted
        from hypa.physics.fmu import remove_extracted_here

        remove_extracted_here()


def _serve_tasks(pipe, runners: Sequence[Any], val: Any) -> None:
    while True:
        try:
            task = pipe.recv()
        except EOFError:
            return
        if task is None:
            return
        try:
            i, share = task
            runner = runners[i]
            runner.advance(share, val)
            error = None if runner.error is None else ValueError(str(runner.error))  # picklable, same text
            pipe.send(("done", (i, {"score": runner.score, "previous": runner.previous, "error": error,
                                    "seconds": runner.seconds, "done": runner.fit.done,
                                    "diverged": runner.fit.diverged, "timed_out": runner.fit.timed_out,
                                    "converged": runner.fit.converged, "promise": runner.promise,
                                    "values": runner.fit.values() if runner.error is None else None})))
        except BaseException:  # noqa: BLE001 - the parent raises it with the worker's traceback
            pipe.send(("failed", traceback.format_exc()))
            return
