"""Where a bake's independent per-prototype solves run (issue #19).

By default they run one after the other in this process. Inside a ``foliage batch`` task (``on_cluster``) they
run as tasks of the batch's own Dask cluster: the asset's task leaves its worker's thread pool while it waits
(``distributed.worker_client``), so a forest of several prototypes spreads its lattice solves over the workers
instead of solving them one at a time on one. The results are the same either way: each solve is a pure
function of its prototype, and the kernels' results do not depend on the number of threads.
"""

from __future__ import annotations

import contextlib
import contextvars
import uuid
from collections.abc import Callable, Iterator, Sequence
from typing import Any, TypeVar

T = TypeVar("T")

#: The active cluster map (``on_cluster``), and the workers it sent each call to.
_CLUSTER: contextvars.ContextVar[tuple[str, list[str | None]] | None] = contextvars.ContextVar("foliage_fanout",
                                                                                                default=None)


def fan_out(fn: Callable[..., T], calls: Sequence[tuple], on_done: Callable[[], Any] | None = None) -> list[T]:
    """``[fn(*args) for args in calls]``, on the batch's cluster inside :func:`on_cluster` when there are several;
    ``on_done()`` after each call ends (progress)."""
    cluster = _CLUSTER.get()
    if cluster is None or len(calls) < 2:
        out = []
        for args in calls:
            out.append(fn(*args))
            if on_done is not None:
                on_done()
        return out
    label, where = cluster
    from distributed import as_completed, worker_client

    with worker_client() as client:
        tag = uuid.uuid4().hex[:8]
        futures = [client.submit(_run_on_worker, fn, args, key=f"{label}-{tag}-{k}", pure=False)
                   for k, args in enumerate(calls)]
        for _ in as_completed(futures):
            if on_done is not None:
                on_done()
        results = client.gather(futures)
    where.extend(worker for _, worker in results)
    return [value for value, _ in results]


@contextlib.contextmanager
def on_cluster(label: str) -> Iterator[list[str | None]]:
    """Inside a Dask task: :func:`fan_out` submits to the task's cluster. Yields the list of the workers each
    fanned-out call ran on, in order (for the batch's record)."""
    where: list[str | None] = []
    token = _CLUSTER.set((label, where))
    try:
        yield where
    finally:
        _CLUSTER.reset(token)


def _run_on_worker(fn: Callable[..., T], args: tuple) -> tuple[T, str | None]:
    """One fanned-out call on a worker, with the worker's share of the cores for numba; (its value, the worker)."""
    from distributed import get_worker

    from foliage_tools.pipeline.batch import share_cores

    share_cores()
    return fn(*args), get_worker().address
