"""``foliage batch``: the stages of ``bake`` for many assets, on Dask distributed, with a content-hash cache.

Each asset is one task: ``run_bake`` into ``OUTROOT/<name>/`` on a Dask
worker, so every asset keeps the bake's own contract (staged, then committed
as one result; a killed run's leftovers finished or removed by the next one).
Tasks are per asset, not per prototype: the bake's stages light every
prototype of a scene together (the forest lattice and the exact direct light
see all instances), so a forest is one task.

The cluster is local by default (``workers`` processes of one thread each,
numba limited to its share of the cores, so the bakes do not oversubscribe
them) or an existing one (``scheduler``, a farm's ``tcp://HOST:PORT``).
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
from foliage_tools.pipeline.bake import BakeParams
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
        reason = "--force" if params.force else why_bake(key, previous.get(a.name), outroot)
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
            p.entry = {**previous[p.asset.name], "status": "cached", "seconds": 0.0, "input": str(p.asset.path),
                       "reason": "inputs, options and tool unchanged since its last bake", "attempts": 0}
            record[p.asset.name] = p.entry
            counts.cached += 1
    if todo:
        counts.queued = len(todo)
        progress.update(counts)  # before the cluster starts, which takes seconds
        _bake_all(todo, outroot, params, record, counts, progress, report)
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


def _entry(p: _Plan, fut, outroot: Path, attempts: int) -> dict:
    """The batch.json entry of a finished task."""
    entry: dict[str, Any] = {"input": str(p.asset.path), "key": p.key.digest, "files": p.key.files, "options": p.key.options,
             "tool": p.key.tool, "reason": p.reason, "attempts": attempts, "status": "failed", "seconds": 0.0,
             "outputs": [], "warnings": [], "error": None}
    if fut.status == "finished":
        result = fut.result()
        entry.update(status=result["status"], seconds=result["seconds"], warnings=result["warnings"],
                     error=result["error"], worker=result["worker"], outputs=[_relative(o, outroot) for o in result["outputs"]])
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
            env={"NUMBA_NUM_THREADS": str(max(1, cores // workers))},
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
    _share_cores()
    started = time.perf_counter()
    result = {"status": "failed", "seconds": 0.0, "outputs": [], "warnings": [], "error": None, "worker": worker}
    try:
        report = run_bake(Path(path), Path(outdir), params)
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


def _share_cores() -> None:
    """numba's threads for this task: the machine's cores shared among the worker's task threads."""
    import numba

    try:
        from distributed import get_worker

        slots = get_worker().state.nthreads
    except ValueError:
        slots = 1
    # numba.config sets its options as module globals at import: not in its type information
    numba.set_num_threads(max(1, min(numba.config.NUMBA_NUM_THREADS, _cores() // max(1, slots))))  # type: ignore[attr-defined]
