"""``foliage batch``: bake many assets on Dask distributed, skipping those whose inputs did not change."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

import click
from rich.markup import escape
from rich.progress import BarColumn, Progress, TaskID, TextColumn, TimeElapsedColumn
from rich.table import Table

from foliage_tools.cli.helpformat import FoliageCommand
from foliage_tools.cli import console
from foliage_tools.cli.bakes import bake, bake_job_options, bake_params
from foliage_tools.cli.common import _long_names, common_options, error_report, run, setup_logging
from foliage_tools.errors import EXIT_FINDINGS, EXIT_INTERRUPTED, FoliageError, UsageError

if TYPE_CHECKING:
    from foliage_tools.pipeline.report import Report
    from foliage_tools.pipeline.stats import BatchStats

#: The bake options an asset of a manifest may set (every option of `foliage bake` but its output and output format).
_NOT_PER_ASSET = {"outdir", "as_json", "quiet", "verbose"}
_BAKE_PARAMS = ("resolution", "with_reference", "reference_paths", "reference_noise", "direct_mode", "direct_samples",
                "sun", "leaf_optics", "wood_reflectance", "volume_purpose", "layer_format", "gather",
                "grid_precision")


class _Bar:
    """The batch's progress: a rich bar on stderr (assets finished of all), with baked / cached / running / failed."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled and console.stderr.is_terminal
        self._progress: Progress | None = None
        self._task: TaskID | None = None
        self._last: str | None = None

    def __enter__(self) -> "_Bar":
        if self.enabled:
            self._progress = Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                                      TimeElapsedColumn(), console=console.stderr, transient=True)
            self._progress.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        if self._progress is not None:
            self._progress.__exit__(*exc)

    def update(self, c) -> None:
        text = f"{c.done} baked, {c.cached} cached, {c.running} running, {c.queued} queued, {c.failed} failed"
        if self._progress is None:
            if text != self._last:  # no bar (not a terminal, or -q): the changes still reach a log (-v)
                logging.getLogger("foliage.batch").info(text)
            self._last = text
            return
        if self._task is None:
            self._task = self._progress.add_task(text, total=c.total)
        self._progress.update(self._task, description=text, completed=c.done + c.cached + c.failed)


def _asset(spec, base, flags: dict):
    """An ``Asset`` of a spec: the batch's options (``base``, ``flags``) with a manifest's own keys over them."""
    from foliage_tools.pipeline.batch import Asset

    if not spec.options:
        return Asset(name=spec.name, path=spec.path, params=base)
    known = {k: v for k, v in _long_names(bake).items() if v not in _NOT_PER_ASSET}
    values = {}
    for key, value in spec.options.items():
        name = key.replace("-", "_")
        if name not in known:
            listed = ", ".join(sorted({k.replace("_", "-") for k in known}))
            raise UsageError(f"{spec.where}: unknown key {key!r}; an asset takes the options of `foliage bake`: {listed}.")
        values[known[name]] = value
    try:
        ctx = bake.make_context("bake", [str(spec.path), "-o", "."], default_map={**flags, **values})
    except click.ClickException as exc:
        raise UsageError(f"{spec.where}: {exc.format_message()}") from None
    ctx.meta["foliage.config"] = str(spec.manifest)  # names the manifest in errors of the values it set
    try:
        with ctx:
            params = bake_params(**{k: ctx.params[k] for k in _BAKE_PARAMS})
    except FoliageError as exc:
        raise UsageError(f"{spec.where}: {exc}") from None
    return Asset(name=spec.name, path=spec.path, params=params)


def _check_scheduler(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    """``--scheduler``: an address Dask can connect to (``tcp://HOST:PORT``, or tls/ws/wss), checked before any
    work instead of after the connect timeout. A bare ``HOST:PORT`` is Dask's ``tcp://HOST:PORT``."""
    if value is None:
        return None
    from distributed.comm import parse_address
    from distributed.comm.registry import get_backend

    try:
        scheme, location = parse_address(value)
    except ValueError as exc:
        raise click.BadParameter(f"{value!r} is not an address ({exc}); give tcp://HOST:PORT.", ctx=ctx,
                                 param=param) from None
    if scheme not in ("tcp", "tls", "ws", "wss"):
        raise click.BadParameter(f"{value!r}: {scheme}:// is not a scheduler address a farm listens on; give "
                                 "tcp://HOST:PORT (or tls://, ws://, wss://).", ctx=ctx, param=param)
    try:
        host, port = get_backend(scheme).get_address_host_port(location)
    except (ValueError, TypeError) as exc:
        raise click.BadParameter(f"{value!r} is not HOST:PORT ({exc}); give tcp://HOST:PORT.", ctx=ctx,
                                 param=param) from None
    if not host or not 0 < port < 65536:
        raise click.BadParameter(f"{value!r}: give a host and a port from 1 to 65535 (tcp://HOST:PORT).", ctx=ctx,
                                 param=param)
    return value


@click.command(cls=FoliageCommand, common=("--output", "--workers", "--scheduler", "--dry-run", "--force", "--resolution"))
@click.argument("inputs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("-o", "--output", "outroot", required=True, type=click.Path(path_type=Path, file_okay=False),
              help="Output root: each asset bakes into OUTROOT/<name>/.")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Local worker processes [default: one per core].")
@click.option("--scheduler", metavar="tcp://HOST:PORT", default=None, callback=_check_scheduler,
              help="Bake on this Dask scheduler (a farm) instead of locally.")
@click.option("--dry-run", is_flag=True, help="Say which assets would bake and why; write nothing.")
@click.option("--force", is_flag=True, help="Bake every asset, even those the cache says are unchanged.")
@bake_job_options
@common_options
def batch(inputs: tuple[Path, ...], outroot: Path, workers: int | None, scheduler: str | None, dry_run: bool, force: bool,
          as_json: bool, quiet: bool, verbose: int, **bake_values) -> None:
    """Bake many assets: the stages of `foliage bake` for each, on Dask distributed, cached by content.

    INPUTS are USD files, directories (searched for USD files) or .toml
    manifests ([[asset]] tables: path, an optional name, any `foliage bake`
    option). Each asset bakes into OUTROOT/<name>/ with the guarantees of
    `foliage bake`; a failing asset fails alone. An asset whose files,
    options and tool are those of its last bake is skipped ("cached").
    OUTROOT/batch.json records every asset (status, key, seconds, outputs,
    warnings, error). Exit codes: 0 all baked or cached; 1 any asset failed;
    2 bad usage or inputs (nothing baked); 130 interrupted.

    \b
    Examples:
      foliage batch examples/tree_small.usda ../shared/assets/ -o out/batch --resolution 32
      foliage batch trees.toml -o out/batch --dry-run
      foliage batch trees/ -o /farm/out/batch --scheduler tcp://10.0.0.5:8786 -v   # -v: the Dask dashboard address
    """
    from foliage_tools.pipeline.batch import BatchParams, run_batch
    from foliage_tools.pipeline.batch_inputs import collect

    ctx = click.get_current_context()

    def body() -> int:
        setup_logging(verbose, quiet)
        params = BatchParams(workers=workers, scheduler=scheduler, dry_run=dry_run, force=force)
        base = bake_params(**{k: bake_values[k] for k in _BAKE_PARAMS})  # the flags' errors are named as `bake` names them
        flags = {k: bake_values[k] for k in _BAKE_PARAMS
                 if ctx.get_parameter_source(k) not in (click.core.ParameterSource.DEFAULT, None)}
        assets = [_asset(spec, base, flags) for spec in collect(list(inputs), outroot)]
        try:
            with _Bar(enabled=not (quiet or as_json or dry_run)) as bar:
                report = run_batch(assets, outroot, params, progress=bar)
        except KeyboardInterrupt:
            message = (f"interrupted; the assets finished so far are recorded in @{outroot / 'batch.json'}@: run the same "
                       "command again to go on from there.")
            console.stderr.print(message, highlight=False, soft_wrap=True)
            if as_json:
                console.print_json(error_report("batch", [str(i) for i in inputs], 0.0, EXIT_INTERRUPTED, "Interrupted", message))
            return EXIT_INTERRUPTED
        entries = report.stats["assets"]
        failed = [name for name, e in entries.items() if e.get("status") == "failed"]
        if as_json:
            console.print_json(report.as_json())
        elif not quiet:
            console.warn(report.warnings, quiet)
            _render(report, dry_run)
        for name in failed:
            e = entries[name]["error"]
            console.error(f"{name} (exit {e['code']}): {e['message']}", "failed")
        return EXIT_FINDINGS if failed else 0

    run(body)


def _render(report: Report[BatchStats], dry_run: bool) -> None:
    s = report.stats
    if dry_run:
        table = Table(title="batch --dry-run: nothing is baked or written")
        for col in ("asset", "would", "why"):
            table.add_column(col, overflow="fold")
        for name, e in s["assets"].items():
            table.add_row(escape(name), e["action"], escape(e["reason"]))
        console.print_table(table)
        return
    if s["workers"] is None:
        where = "no cluster (nothing to bake)"
    else:
        where = f"{s['scheduler']} ({s['workers']} workers)" if s["scheduler"] else f"a local cluster of {s['workers']} worker(s)"
    c = s["counts"]
    table = Table(title=f"batch: {c['baked']} baked, {c['cached']} cached, {c['failed']} failed in {report.seconds:.1f} s on {where}")
    for col in ("asset", "status", "seconds", "result or error"):
        table.add_column(col, justify="right" if col == "seconds" else "left", overflow="fold")
    for name, e in s["assets"].items():
        outcome = e["error"]["message"] if e.get("error") else next((o for o in e["outputs"] if o.endswith((".lb.usda", ".lb.usdc"))), "")
        table.add_row(escape(name), e["status"], f"{e['seconds']:.1f}", escape(outcome))
    console.print_table(table)
    console.stdout.print(f"wrote {report.outputs[-1]}", highlight=False, soft_wrap=True)
