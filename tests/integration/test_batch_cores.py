"""``foliage batch`` shares the host's cores among the tasks running on it, re-shared as tasks start and end.

A real local cluster of the batch's own making (``batch._client``: two workers of one thread each). One task is
held running on one worker (a Dask ``Event``) while ``_share_cores`` runs as a task on the other, then again once
the held task has ended. The thread counts it sets are the host's cores divided by the tasks running on it (two,
then one), capped by numba's thread pool: with the old static share (cores // workers) the second count would
stay at half the cores, and the batch's last large asset ran on half the machine.
"""

from __future__ import annotations

import pytest

from foliage_tools.pipeline.batch import BatchParams, _client, _cores, _share_cores

distributed = pytest.importorskip("distributed")


def _hold(started: str, release: str) -> int:
    from distributed import Event

    Event(started).set()
    if not Event(release).wait(120):
        raise TimeoutError("the test never released the held task")
    return 0


def test_a_task_takes_the_cores_that_other_tasks_on_its_host_leave():
    from distributed import Event

    cores = _cores()
    with _client(BatchParams(workers=2), tasks=2) as client:
        started, release = Event("held-started", client=client), Event("held-release", client=client)
        held = client.submit(_hold, "held-started", "held-release", pure=False)
        assert started.wait(120), "the held task did not start"
        beside = client.submit(_share_cores, pure=False).result(timeout=120)
        release.set()
        held.result(timeout=120)
        alone = client.submit(_share_cores, pure=False).result(timeout=120)
    assert beside == max(1, cores // 2)
    assert alone == cores
