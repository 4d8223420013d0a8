"""How a stage's work runs: the worker settings, checked once where they enter (the API or a stage
called directly), then passed down as a typed value; the checkpoint interval.

A build used to work out ``workers or default_workers()`` and check it in three places (the build,
the estimate stage, and again before its Monte Carlo); now :func:`worker_settings` resolves the
default and checks the count, the memory the workers need and the executor's name once, and the
stages take the :class:`WorkerSettings` it returns.
"""

from __future__ import annotations

import dataclasses

from firmtool.errors import InputError
from firmtool.estimation.budgets import check_workers
from firmtool.problem import Problem
from firmtool.util import arguments

# Seconds between checkpoints of the estimate stage (finished edges written to /edge_cache).
CHECKPOINT_SECONDS = 10.0
EXECUTORS = ("process", "dask")


@dataclasses.dataclass(frozen=True)
class WorkerSettings:
    """Where the parallel work of a command runs (checked: build one with :func:`worker_settings`).

    Attributes
    ----------
    workers : int
        Local worker processes (``1``: everything runs in this process), or the workers of the
        LocalCluster that ``executor="dask"`` starts without a ``scheduler``.
    executor : ``"process"`` or ``"dask"``.
    scheduler : str or None
        A dask scheduler's address (its cluster's workers are used as they are).
    requested : bool
        Whether ``workers`` was asked for rather than defaulted: an estimate stage with nothing to
        estimate reports 0 workers unless a count was asked for (what it reported before).
    """

    workers: int
    executor: str = "process"
    scheduler: str | None = None
    requested: bool = False


def check_executor(executor: str, scheduler: str | None = None) -> None:
    """Refuse an unknown executor, or a dask scheduler address dask cannot parse (one line naming
    ``--executor`` or ``--scheduler``, not dask's own error deep inside the first stage)."""
    if executor not in EXECUTORS:
        raise InputError(f"--executor: expected 'process' or 'dask', found {executor!r}")
    arguments.scheduler_address(scheduler)


def worker_settings(workers: int | None, executor: str = "process", scheduler: str | None = None, *,
                    default: int, problem: Problem | None = None) -> WorkerSettings:
    """Check the worker settings of a command once, where they enter.

    Parameters
    ----------
    workers : the count asked for, or None for ``default``.
    executor, scheduler : see :class:`WorkerSettings`.
    default : the count without one asked for (all cores for a build or an estimate stage, 1 for a
        design stage: :func:`firmtool.estimation.executors.default_workers`).
    problem : the problem the workers will run; with it, their memory is checked too.

    Raises
    ------
    InputError
        A count that is not an integer >= 1, more than this machine's cores allow, or more than its
        memory holds (:func:`firmtool.estimation.budgets.check_workers`); an unknown executor, a
        scheduler address that is not one (:func:`firmtool.util.arguments.scheduler_address`).
    """
    count = check_workers(default if workers is None else workers, problem)
    check_executor(executor, scheduler)
    return WorkerSettings(workers=count, executor=executor, scheduler=scheduler, requested=workers is not None)
