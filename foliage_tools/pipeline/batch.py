"""``foliage batch``: the stages of ``bake`` for many assets, on Dask distributed, with a content-hash cache.

Each asset is one task: ``run_bake`` into ``OUTROOT/<name>/`` on a Dask
worker, so every asset keeps the bake's own contract (staged, then committed
as one result; a killed run's leftovers finished or removed by the next one).
Tasks are per asset, not per prototype: the bake's stages light every
prototype of a scene together (the forest lattice and the exact direct light
see all instances), so a forest is one task.

The cluster is local by default (``workers`` processes of one thread each)
or an existing one (``scheduler``, a farm's ``tcp://HOST:PORT``). A task's
numba threads are its host's cores divided by the tasks running there,
re-shared at each step of its bake (``_CoreShare``): the bakes do not
oversubscribe the cores, and the last large asset of a batch takes the cores
the others leave.
Assets whose key is unchanged (``batch_cache``) are not sent at all; when
nothing is left to bake no cluster is started.

Isolation: a task never raises. A bad input (exit 2), a failed accuracy
check (1) or a crash (3, with its traceback) come back as a failed result;
a worker that dies mid-asset is replaced, and Dask runs the asset again on
another worker (up to ``distributed.scheduler.allowed-failures`` times,
then it is reported failed). batch.json is rewritten after every asset.
"""

from __future__ import annotations

import logging
import os
import secrets
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from foliage_tools.errors import EXIT_BAD_INPUT, EXIT_INTERNAL, FoliageError, OutputError, UsageError
from foliage_tools.pipeline.bake import BakeParams, portable_copies, planned_outputs
from foliage_tools.pipeline.batch_cache import Key, asset_key, load_record, why_bake, write_record
from foliage_tools.pipeline.report import Report
from foliage_tools.pipeline.stats import BatchStats

if TYPE_CHECKING:
    from distributed import Client, LocalCluster

log = logging.getLogger("foliage.batch")

#: Seconds to wait for a scheduler given with ``--scheduler`` to answer.
CONNECT_TIMEOUT = 20


@dataclass(frozen=True)
class Asset:
    """One asset to bake: its name (OUTROOT/<name>/), its file and its bake options."""

    name: str
    path: Path
    params: BakeParams


@dataclass(frozen=True)
class BatchParams:
    workers: int | None = None
    """Local cluster: worker processes (one thread each); None: one per core, at most one per asset to bake."""
    scheduler: str | None = None
    """An existing Dask scheduler (``tcp://HOST:PORT``) instead of a local cluster."""
    dry_run: bool = False
    """Say what would bake and why (from the cache); bake nothing, write nothing."""
    force: bool = False
    """Bake every asset, whatever the cache says."""

    def __post_init__(self) -> None:
        if self.workers is not None and self.scheduler is not None:
            raise UsageError("--workers sizes the local cluster and --scheduler uses an existing one: give one of them "
                             "(a farm's workers are started with `dask worker ADDR --nthreads 1`).")
        if self.workers is not None and self.workers < 1:
            raise UsageError(f"--workers must be at least 1, got {self.workers}.")


@dataclass
class Counts:
    """What the progress display shows."""

    total: int = 0
    cached: int = 0
    done: int = 0
    failed: int = 0
    running: int = 0
    queued: int = 0


class BatchProgress(Protocol):
    def update(self, counts: Counts) -> None: ...


class _Silent:
    def update(self, counts: Counts) -> None:
        pass


@dataclass
class _Plan:
    asset: Asset
    key: Key
    reason: str | None
    """Why it bakes; None: cached."""
    entry: dict = field(default_factory=dict)


def run_batch(assets: list[Asset], outroot: Path, params: BatchParams, *, progress: BatchProgress | None = None) -> Report[BatchStats]:
    """Bake ``assets`` into ``outroot`` (module docstring). ``stats.assets`` holds each one's batch.json entry."""
    from foliage_tools.scene.atomic import recover

    progress = progress or _Silent()
    report: Report[BatchStats] = Report(command="batch", inputs=[str(a.path) for a in assets])
    outroot = Path(outroot)
    if outroot.exists() and not outroot.is_dir():
        raise OutputError(f"@{outroot}@ exists and is not a directory; give a directory for the batch (OUTROOT).")
    previous = load_record(outroot)
    plans = []
    for a in assets:
        key = asset_key(a.path, a.params)
        reason = "--force" if params.force else why_bake(key, previous.get(a.name), outroot, name=a.name)
        plans.append(_Plan(asset=a, key=key, reason=reason))
    todo = [p for p in plans if p.reason is not None]
    report.stats = {"dry_run": params.dry_run, "workers": None, "scheduler": params.scheduler, "dashboard": None,
                    "assets": {}}
    if params.dry_run:
        for p in plans:
            report.stats["assets"][p.asset.name] = {"input": str(p.asset.path), "action": "bake" if p.reason else "cached",
                                                    "reason": p.reason or "inputs, options and tool unchanged",
                                                    "key": p.key.digest, "options": p.key.options}
        return report.finish()
    if todo:
        outroot.mkdir(parents=True, exist_ok=True)  # bake's own check names an unwritable place, per asset
    recover(outroot, ["batch.json"], report.warnings)  # a record a killed run was renaming into place
    record = dict(previous)
    counts = Counts(total=len(plans))
    for p in plans:
        if p.reason is None:
            # nothing ran for it now: no worker, no threads (the earlier bake's stay in the earlier record only)
            p.entry = {**previous[p.asset.name], "status": "cached", "seconds": 0.0, "input": str(p.asset.path),
                       "reason": "inputs, options and tool unchanged since its last bake", "attempts": 0,
                       "worker": None, "threads": []}
            record[p.asset.name] = p.entry
            counts.cached += 1
    if todo:
        counts.queued = len(todo)
        progress.update(counts)  # before the cluster starts, which takes seconds
        try:
            _bake_all(todo, outroot, params, record, counts, progress, report)
        except BaseException:
            _tidy(todo, outroot)
            raise
    write_record(outroot, record)
    progress.update(counts)
    for p in plans:
        report.stats["assets"][p.asset.name] = p.entry
        report.outputs += [str(outroot / o) for o in p.entry.get("outputs", [])]
        if p.reason is not None:  # a cached asset's warnings were reported when it baked (batch.json keeps them)
            report.warnings += [f"{p.asset.name}: {w}" for w in p.entry.get("warnings", [])]
    report.outputs.append(str(outroot / "batch.json"))
    report.stats["counts"] = {"assets": counts.total, "baked": counts.done, "cached": counts.cached, "failed": counts.failed}
    return report.finish()


def _bake_all(todo: list[_Plan], outroot: Path, params: BatchParams, record: dict, counts: Counts,
              progress: BatchProgress, report: Report) -> None:
    """Send ``todo`` to the cluster; record each result in batch.json as it arrives."""
    import distributed

    topic = f"foliage-batch-{secrets.token_hex(4)}"
    with _client(params, len(todo)) as client, client.as_current():
        report.stats["workers"] = len(client.scheduler_info(n_workers=-1)["workers"])
        report.stats["dashboard"] = client.dashboard_link if _has_dashboard(client) else None
        if report.stats["dashboard"]:
            log.info("Dask dashboard: %s", report.stats["dashboard"])
        else:
            log.info("no Dask dashboard (install bokeh>=3.1 for one)")
        futures = {}
        for p in todo:
            out = outroot / p.asset.name
            fut = client.submit(bake_asset, p.asset.name, str(p.asset.path), str(out), p.asset.params, topic,
                                key=f"foliage-bake-{p.asset.name}-{topic}", pure=False)
            futures[fut] = p
        pending = set(futures)
        try:
            while pending:
                try:
                    done, pending = distributed.wait(pending, timeout=0.5, return_when="FIRST_COMPLETED")
                except TimeoutError:
                    done = set()
                starts = [m["asset"] for _, m in client.get_events(topic) if m.get("event") == "started"]
                for fut in done:
                    p = futures[fut]
                    p.entry = _entry(p, fut, outroot, max(1, starts.count(p.asset.name)))
                    record[p.asset.name] = p.entry
                    if p.entry["status"] == "failed":
                        counts.failed += 1
                    else:
                        counts.done += 1
                    write_record(outroot, record)
                counts.running = len(set(starts) & {futures[f].asset.name for f in pending})
                counts.queued = len(pending) - counts.running
                progress.update(counts)
        except BaseException:
            client.cancel(list(pending), force=True)
            raise


def _tidy(todo: list[_Plan], outroot: Path) -> None:
    """After an interrupted batch (its cluster closed): what its killed tasks left in OUTROOT/<name>/ is removed.

    A worker killed outright (SIGTERM to the batch's process group, SIGKILL) cannot remove its bake's staging
    folder; its process is gone once the cluster is closed, so the staging folder is a dead run's, which
    ``atomic.recover`` removes (or finishes, had its commit begun), as the next bake of the asset would.
    """
    from foliage_tools.scene.atomic import recover

    for p in todo:
        outdir = outroot / p.asset.name
        try:
            # the bake's own planned names (either layer format: reading the input again to choose is not worth it)
            names = {n for ext in ("usda", "usdc") for n in planned_outputs(p.asset.path, p.asset.params, ext)}
            recover(outdir, sorted(names), [], label=f"{Path(p.asset.path).stem}.bake",
                    allow=portable_copies(p.asset.path, outdir, p.asset.params))
            outdir.rmdir()  # only if the bake left it empty
        except (FoliageError, OSError):
            pass


def _entry(p: _Plan, fut, outroot: Path, attempts: int) -> dict:
    """The batch.json entry of a finished task."""
    entry: dict[str, Any] = {"input": str(p.asset.path), "key": p.key.digest, "files": p.key.files, "options": p.key.options,
             "tool": p.key.tool, "reason": p.reason, "attempts": attempts, "status": "failed", "seconds": 0.0,
             "outputs": [], "warnings": [], "error": None}
    if fut.status == "finished":
        result = fut.result()
        entry.update(status=result["status"], seconds=result["seconds"], warnings=result["warnings"],
                     error=result["error"], worker=result["worker"], threads=result["threads"], outputs=[_relative(o, outroot) for o in result["outputs"]])
    else:
        exc = fut.exception()
        kind = type(exc).__name__
        if kind == "KilledWorker":
            message = (f"the worker baking @{p.asset.path}@ died {attempts} time(s) (killed, or out of memory?); "
                       "see the Dask worker logs, then run the batch again to retry it.")
        else:
            message = f"{kind}: {exc}"
        entry["error"] = {"code": EXIT_INTERNAL, "type": kind, "message": message}
    if attempts > 1 and entry["status"] != "failed":
        entry["warnings"] = [f"baked at attempt {attempts}: the worker of an earlier attempt died", *entry["warnings"]]
    return entry


def _relative(path: str, outroot: Path) -> str:
    p = Path(path)
    try:
        return str(p.resolve().relative_to(outroot.resolve()))
    except ValueError:
        return str(p)


def _has_dashboard(client) -> bool:
    try:
        return "dashboard" in client.scheduler_info(n_workers=0).get("services", {})
    except Exception:
        return False


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


class _client:
    """A Dask client: on ``params.scheduler``, or on a local cluster it starts and stops."""

    def __init__(self, params: BatchParams, tasks: int) -> None:
        self.params, self.tasks = params, tasks
        self.cluster: LocalCluster | None = None
        self.client: Client | None = None

    def __enter__(self):
        from distributed import Client, LocalCluster

        if self.params.scheduler:
            try:
                self.client = Client(self.params.scheduler, timeout=CONNECT_TIMEOUT, set_as_default=False)
            except (OSError, TimeoutError) as exc:
                raise UsageError(f"cannot reach the Dask scheduler at {self.params.scheduler} ({exc}); is `dask scheduler` "
                                 "running there, and is the address tcp://HOST:PORT?") from None
            return self.client
        if not log.isEnabledFor(logging.DEBUG):  # -v shows the batch's progress and dashboard, -vv Dask's own log
            logging.getLogger("distributed").setLevel(logging.WARNING)
        cores = _cores()
        workers = self.params.workers or max(1, min(cores, self.tasks))
        self.cluster = LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
            silence_logs=logging.WARNING,
            # each worker may use every core, and uses its share of them (``_CoreShare``)
            env={"NUMBA_NUM_THREADS": str(cores)},
        )
        self.client = Client(self.cluster, set_as_default=False)
        return self.client

    def __exit__(self, *exc) -> None:
        if self.client is not None:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def bake_asset(name: str, path: str, outdir: str, params: BakeParams, topic: str) -> dict:
    """The task, on a worker: ``run_bake`` of one asset. Never raises: a failure is a result with ``error`` set."""
    from foliage_tools.pipeline.bake import run_bake

    worker = _announce(topic, name)
    share = _CoreShare()
    share.step("start")
    started = time.perf_counter()
    result = {"status": "failed", "seconds": 0.0, "outputs": [], "warnings": [], "error": None, "worker": worker}
    try:
        report = run_bake(Path(path), Path(outdir), params, progress=share)
    except FoliageError as exc:
        result["error"] = {"code": exc.exit_code, "type": type(exc).__name__, "message": str(exc)}
    except MemoryError:
        result["error"] = {"code": EXIT_BAD_INPUT, "type": "MemoryError",
                           "message": f"baking @{path}@ needs more memory than the worker has; lower --resolution."}
    except Exception as exc:  # our bug: the traceback stands in for the crash log
        result["error"] = {"code": EXIT_INTERNAL, "type": type(exc).__name__, "message": f"internal error: {exc}",
                           "traceback": traceback.format_exc()}
    else:
        result.update(outputs=report.outputs, warnings=report.warnings)
        if report.findings:  # written, but the bake failed its own accuracy check (exit 1 of `foliage bake`)
            result["error"] = {"code": 1, "type": "FindingsError", "message": "; ".join(report.findings)}
        else:
            result["status"] = "baked"
    result["seconds"] = round(time.perf_counter() - started, 3)
    result["threads"] = share.threads
    return result


def _announce(topic: str, name: str) -> str | None:
    """Tell the client this asset started (its progress counts it as running; two starts mean a retry); the worker's address."""
    try:
        from distributed import get_worker

        worker = get_worker()
    except ValueError:  # not on a worker (called directly)
        return None
    worker.log_event(topic, {"asset": name, "event": "started", "pid": os.getpid()})
    return worker.address


#: ``_CoreShare`` asks the scheduler at most this often (seconds).
SHARE_INTERVAL = 1.0


class _CoreShare:
    """The progress of a batch task: at each step of the bake, numba's threads re-shared (``_share_cores``).

    A bake announces every stage and advances through its long loops, so when the other tasks on the host end (the
    batch's last large asset), this one takes their cores from its next step on; when tasks start
    beside it again it gives them back at its next step. It asks the scheduler at most once per
    ``SHARE_INTERVAL``.
    """

    def __init__(self) -> None:
        self.threads: list[tuple[float, int]] = []  # (seconds into the task, thread count) at each change
        self._start = time.monotonic()
        self._next = 0.0

    def step(self, message: str, total: int | None = None) -> None:
        now = time.monotonic()
        if now >= self._next:
            self._next = now + SHARE_INTERVAL
            n = _share_cores()
            if not self.threads or self.threads[-1][1] != n:
                self.threads.append((round(now - self._start, 1), n))

    def advance(self, n: int = 1) -> None:
        self.step("")


def _running_on_host(dask_scheduler: Any, host: str) -> int:
    """On the scheduler: tasks executing on the workers of ``host`` (each worker at most its thread count)."""
    return sum(min(len(ws.processing), ws.nthreads) for ws in dask_scheduler.workers.values() if ws.host == host)


def _share_cores() -> int:
    """numba's threads for this task: the host's cores shared among the tasks running on it; the count set.

    Off a worker (called directly), or when the scheduler cannot say, the worker's own thread slots
    stand in for the tasks (a farm's workers started with ``--nthreads 1`` each get their share).
    """
    import numba

    busy = 1
    try:
        from distributed import get_client, get_worker
        from distributed.comm import get_address_host

        worker = get_worker()
        busy = worker.state.nthreads
        try:
            busy = get_client().run_on_scheduler(_running_on_host, host=get_address_host(worker.address))
        except Exception as exc:  # a scheduler that refuses run_on_scheduler: the static share
            log.debug("cannot ask the scheduler for the tasks on this host (%s); sharing by thread slots", exc)
    except ValueError:
        pass
    # numba.config sets its options as module globals at import: not in its type information
    n = max(1, min(numba.config.NUMBA_NUM_THREADS, _cores() // max(1, busy)))  # type: ignore[attr-defined]
    numba.set_num_threads(n)
    return n
