"""What every ``foliage`` subcommand shares: argument decorators and the error handling.

``run`` is the one place where failures become exit codes (DESIGN.md section
3): 0 ok, 1 findings, 2 bad usage or input, 3 internal error (with a crash
log), 130 interrupted.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import errno
import logging
import math
import os
import sys
import tempfile
import time
import traceback
from pathlib import Path
from typing import Callable, Iterator

import click

from foliage_tools import __version__
from foliage_tools.cli import console
from foliage_tools.errors import EXIT_BAD_INPUT, EXIT_FINDINGS, EXIT_INTERNAL, EXIT_INTERRUPTED, FoliageError, OutputError
from foliage_tools.pipeline.report import Progress, Report, S

#: Bytes of a file name that the writes need beyond the name itself: USD's save writes a temporary beside the layer
#: whose name is the layer's and a little more (a .usda of 254 bytes fails, 253 is written).
NAME_ROOM = 8


def check_output_name(ctx: click.Context, param: click.Parameter, value: Path | None) -> Path | None:
    """``-o``: a file name that fits its filesystem with room for the temporaries the writes make, and holds no
    control character, refused before any work (either made USD's save fail after the work)."""
    if value is None:
        return None
    control = [c for c in str(value) if ord(c) < 32 or ord(c) == 127]
    if control:  # USD refuses them in the asset paths a layer writes (its grids'), after the work
        raise click.BadParameter(f"@{console.printable(str(value))}@ has the control character {control[0]!r} in it, which USD asset paths "
                                 "cannot hold: choose a name without it.", ctx=ctx, param=param)
    parent = value.parent if str(value.parent) else Path(".")
    try:
        limit = os.pathconf(parent, "PC_NAME_MAX")
    except (OSError, ValueError):  # a folder that does not exist yet is named by the output checks
        limit = 255
    size = len(os.fsencode(value.name))
    if size > limit - NAME_ROOM:
        raise click.BadParameter(f"@{value}@: the file name is {size} bytes long; the writes need it at most "
                                 f"{limit - NAME_ROOM} bytes on this filesystem (it allows {limit}, and a temporary "
                                 "beside the output takes the rest): choose a shorter name.", ctx=ctx, param=param)
    ctx.meta.setdefault(OUTPUT_FOLDERS, []).append(parent)
    return value


#: ``ctx.meta`` key: the folders the command's output files go into (:func:`check_output_name`), made by
#: :func:`execute` before the work when they are missing.
OUTPUT_FOLDERS = "foliage.output_folders"


@contextlib.contextmanager
def output_folders(folders: list[Path]) -> Iterator[None]:
    """Make the missing ``folders`` (and those above them) before the work; if the work fails, remove again the
    ones made here that are still empty, so a failed run leaves nothing behind."""
    made: list[Path] = []
    try:
        for folder in folders:
            missing = []
            d = folder.absolute()
            while not d.exists() and d != d.parent:
                missing.append(d)
                d = d.parent
            for d in reversed(missing):
                try:
                    d.mkdir()
                except FileExistsError:
                    continue
                except OSError as exc:
                    raise OutputError(f"@{folder}@: cannot create the folder {d} ({exc.strerror}); choose another "
                                      "output path.") from None
                made.append(d)
        yield
    except BaseException:
        for d in reversed(made):  # deepest first
            try:
                d.rmdir()
            except OSError:  # not empty (or gone): it holds something now, which is not ours to remove
                pass
        raise


def check_scene(ctx: click.Context, param: click.Parameter, value: Path | None) -> Path | None:
    """SCENE of a command that writes a layer over it: no control character in its path, which the layer names as
    its sublayer and USD asset paths cannot hold (refused before any work; inspect and validate read it)."""
    if value is None or not any(p.name in ("out", "outdir", "outroot") for p in ctx.command.params):
        return value
    control = [c for c in str(value) if ord(c) < 32 or ord(c) == 127]
    if control:
        raise click.BadParameter(f"@{console.printable(str(value))}@ has the control character {control[0]!r} in it, and the layer written "
                                 "over it names it as a USD asset path, which cannot hold one: rename the file (or "
                                 "link it) to a name without it.", ctx=ctx, param=param)
    return value


SCENE = click.argument("scene", type=click.Path(path_type=Path, dir_okay=True), callback=check_scene)
OUT = click.option("-o", "--output", "out", required=True, type=click.Path(path_type=Path), callback=check_output_name, help="Output layer (.usda/.usdc); .vdb grids go beside it.")
JSON = click.option("--json", "as_json", is_flag=True, help="One JSON report on stdout, no tables.")


def common_options(fn: Callable) -> Callable:
    fn = click.option("-v", "--verbose", count=True, help="More log output (-vv: debug).")(fn)
    fn = click.option("-q", "--quiet", is_flag=True, help="No progress, warnings or tables; errors still print.")(fn)
    return JSON(fn)


def crash_log(exc: BaseException) -> Path:
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "foliage-tools"
    try:
        base.mkdir(parents=True, exist_ok=True)
    except OSError:
        base = Path(tempfile.gettempdir())
    path = base / f"crash-{_dt.datetime.now().strftime('%Y%m%d-%H%M%S')}-{os.getpid()}.log"
    path.write_text(
        f"foliage {__version__}\nargv: {sys.argv}\n\n" + "".join(traceback.format_exception(exc)), encoding="utf-8"
    )
    return path


#: The name of the signal that interrupted the run (SIGTERM, SIGHUP), set by ``main``'s handler; None for Ctrl-C.
last_signal: str | None = None


def interrupted_message(exc: BaseException | None) -> str:
    from foliage_tools.scene.atomic import InterruptedAfterCommit

    how = f"interrupted ({last_signal})" if last_signal else "interrupted"
    if isinstance(exc, InterruptedAfterCommit):  # held back until the result was whole (scene.atomic)
        return f"{how} just after the outputs were written: {', '.join(map(str, exc.paths))}."
    return f"{how}; no output was written."


#: errno values that are the environment's doing, not a bug (exit 2, naming the file): what to do about each.
ENVIRONMENT_ERRNOS = {
    errno.ENOSPC: "free some space or choose another output path",
    errno.EDQUOT: "free some space or choose another output path",
    errno.ENAMETOOLONG: "choose a shorter path",
    errno.EROFS: "choose a writable output path",
    errno.EACCES: "check the permissions or choose another path",
    errno.EPERM: "check the permissions or choose another path",
    errno.EMFILE: "raise the open-file limit (ulimit -n)",
    errno.EIO: "check the disk or the network filesystem",
}


def run(body: Callable[[], int]) -> None:
    """Run a command body, mapping every outcome to an exit code (and, with ``--json``, a JSON error object)."""
    started = time.perf_counter()
    try:
        code = body()
    except FoliageError as exc:
        code = _fail(started, exc.exit_code, type(exc).__name__, str(exc))
    except KeyboardInterrupt as exc:
        console.stderr.print(interrupted_message(exc), highlight=False, soft_wrap=True)
        code = EXIT_INTERRUPTED
        _json_error(started, code, "Interrupted", interrupted_message(exc))
    except (click.exceptions.Exit, click.ClickException):
        raise
    except console.OutputLost as exc:  # the report could not reach stdout: say so on stderr
        code = _fail(started, EXIT_BAD_INPUT, "OutputError", str(exc))
    except OSError as exc:
        code = os_failure(exc, started)
    except (MemoryError, ImportError, RecursionError) as exc:
        code = _fail(started, EXIT_BAD_INPUT, *environment_failure(exc))
    except RuntimeError as exc:
        if "can't start new thread" in str(exc):  # no memory left for a thread's stack
            code = _fail(started, EXIT_BAD_INPUT, "MemoryError", memory_message(exc))
        else:
            code = _internal(started, exc)
    except Exception as exc:  # the top-level handler: anything else is our bug
        code = _internal(started, exc)
    sys.exit(console.finish(code))


def os_failure(exc: OSError, started: float = 0.0) -> int:
    """An OSError's exit code, said on stderr (and as the JSON error): the environment's (:data:`ENVIRONMENT_ERRNOS`,
    exit 2 naming the file), else an internal error (exit 3, crash log)."""
    if exc.errno not in ENVIRONMENT_ERRNOS:
        return _internal(started, exc)
    where = f"@{exc.filename}@: " if exc.filename else ""  # DESIGN.md section 3: exit 2, naming the file
    return _fail(started, EXIT_BAD_INPUT, "EnvironmentError", f"{where}{exc.strerror or exc}; {ENVIRONMENT_ERRNOS[exc.errno]}.")


def environment_failure(exc: BaseException) -> tuple[str, str]:
    """The error type and message (exit 2) of a MemoryError, an ImportError or a RecursionError: out of memory
    (:func:`memory_message`), a module that is missing or broken, or an input nested deeper than Python follows."""
    if isinstance(exc, RecursionError):  # a --config of arrays in arrays, ...
        return "InputError", f"an input is nested too deeply to read ({exc}); flatten it."
    if lacks_memory(exc):
        return "MemoryError", memory_message(exc)
    return "EnvironmentError", missing_module_message(exc)


#: The address space (``ulimit -v``) the libraries need to load and a small bake to run, measured on 2 cores
#: (``lb`` at resolution 8: killed by SIGSEGV inside USD's or numba's start-up at 1,800 MB, whole at 2,200 MB).
#: Below it they crash in C code, where no message can be given, so a lower limit is refused up front.
MIN_ADDRESS_SPACE_MB = 2200


def address_space_problem() -> str | None:
    """The exit-2 message when the address-space limit (``ulimit -v``) is below :data:`MIN_ADDRESS_SPACE_MB`."""
    import resource

    soft, _hard = resource.getrlimit(resource.RLIMIT_AS)
    if soft == resource.RLIM_INFINITY or soft >= MIN_ADDRESS_SPACE_MB << 20:
        return None
    return (f"this job needs more memory than is available (before loading its libraries): the address-space limit "
            f"is {soft >> 20:,} MB (ulimit -v {soft >> 10}) and foliage needs at least {MIN_ADDRESS_SPACE_MB:,} MB to "
            f"load USD, OpenVDB and numba (below that they crash); raise it (ulimit -v {MIN_ADDRESS_SPACE_MB << 10} "
            "or more, or unlimited).")


#: What the errors of a library that could not get memory say (dlopen's ENOMEM, C++'s std::bad_alloc, numpy's).
_NO_MEMORY = ("cannot allocate memory", "failed to map segment", "out of memory", "bad_alloc", "unable to allocate",
              "memoryerror")


def lacks_memory(exc: BaseException) -> bool:
    """Whether ``exc`` (a MemoryError, or an ImportError from a library that could not be loaded) comes from a lack
    of memory: the exception or one it was raised from is a MemoryError, or its message says so. "cannot allocate
    memory in static TLS block" is a loader limit, not memory, and is not counted."""
    seen: set[int] = set()
    cur: BaseException | None = exc
    while cur is not None and id(cur) not in seen:
        seen.add(id(cur))
        text = str(cur).lower()
        if isinstance(cur, MemoryError) or (any(s in text for s in _NO_MEMORY) and "static tls" not in text):
            return True
        cur = cur.__cause__ or cur.__context__
    return False


def memory_message(exc: BaseException) -> str:
    """exit 2 "needs more memory", naming the step it happened at (the progress step, or the library loading)."""
    module = _failed_module(exc)
    if module is not None:
        stage = f"while loading the {module} library"
    elif isinstance(exc, ImportError):
        stage = f"while loading a library: {exc}"
    elif console.last_step:
        stage = f"at the step {console.shown_path(console.last_step)!r}"
    else:
        stage = "before the first step"
    return (f"this job needs more memory than is available ({stage}); raise the memory limit (ulimit -v) or lower "
            "the job's size (--resolution, --directions, --paths, ...). `foliage plan` estimates the memory of a bake.")


def _failed_module(exc: BaseException) -> str | None:
    """The top-level module whose import raised ``exc``, if the traceback shows one (an ImportError's name, or the
    first frame of an import in progress)."""
    name = getattr(exc, "name", None)
    if isinstance(exc, ImportError) and name:
        return name.split(".")[0]
    tb = exc.__traceback__
    while tb is not None:
        code = tb.tb_frame.f_code
        if code.co_name == "<module>" and tb.tb_frame.f_globals.get("__name__") not in (None, "__main__"):
            return tb.tb_frame.f_globals["__name__"].split(".")[0]
        tb = tb.tb_next
    return None


def missing_module_message(exc: BaseException) -> str:
    name = getattr(exc, "name", None)
    what = f"the module {name!r}" if name else "a module"
    return (f"{what} could not be imported ({exc}): this Python lacks one of foliage-tools' dependencies, or has a "
            "broken one; reinstall them (`pip install -e .`, and Debian's python3-openvdb for pyopenvdb).")


def _fail(started: float, code: int, kind: str, message: str) -> int:
    """Say ``message`` on stderr, with ``--json`` as the JSON error object too, and return ``code``."""
    console.error(message)
    _json_error(started, code, kind, message)
    return code


def _internal(started: float, exc: BaseException) -> int:
    log = crash_log(exc)
    console.error(f"{type(exc).__name__}: {exc}\nA crash log is at {log}; please attach it to a bug report.", "internal error")
    _json_error(started, EXIT_INTERNAL, type(exc).__name__, f"internal error: {exc}", crash_log=str(log))
    return EXIT_INTERNAL


def error_report(command: str | None, inputs: list[str], seconds: float, code: int, kind: str, message: str, **extra) -> dict:
    """The ``--json`` object of a failed run: the report's fields, empty, and ``error`` (schemas/json/report.schema.json)."""
    return {
        "command": command or "foliage", "version": __version__, "inputs": inputs, "outputs": [],
        "seconds": round(seconds, 6), "warnings": [], "stats": {},
        "error": {"code": code, "type": kind, "message": message, **extra},
    }


def _json_error(started: float, code: int, kind: str, message: str, **extra) -> None:
    """With ``--json``, a failure still prints one JSON object on stdout, with ``error`` set (DESIGN.md section 3)."""
    ctx = click.get_current_context(silent=True)
    if ctx is None or not ctx.params.get("as_json"):
        return
    scene = ctx.params.get("scene", ctx.params.get("model"))  # import: MODEL
    given = ctx.params.get("inputs")  # batch: INPUTS...
    inputs = [str(scene)] if scene is not None else [str(i) for i in given] if given else []
    try:
        console.print_json(error_report(ctx.info_name, inputs, time.perf_counter() - started, code, kind, message, **extra))
    except console.OutputLost:  # stdout is gone (a closed pipe): the exit code and stderr still say it
        pass


#: The loggers ``-v`` / ``-vv`` open: the tool's own (``foliage`` for the CLI's steps, ``foliage_tools.*`` for the
#: stages and solvers). Libraries' loggers (numba, distributed, ...) are left as they are: ``-vv`` must not flood
#: stderr with numba's compiler trace.
OWN_LOGGERS = ("foliage", "foliage_tools")


class _StderrHandler(logging.StreamHandler):
    """Writes to the ``sys.stderr`` of the moment (a test runner swaps it between invocations)."""

    @property  # type: ignore[override]
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, _value) -> None:
        pass

    def format(self, record: logging.LogRecord) -> str:
        return console.printable(super().format(record))  # a path with an escape sequence in it is shown, not acted on


def setup_logging(verbose: int, quiet: bool) -> None:
    """``-q`` errors only, default warnings, ``-v`` info (steps, solver choices, timings), ``-vv`` debug; on stderr,
    so ``--json`` stdout stays one JSON object."""
    level = logging.ERROR if quiet else (logging.WARNING, logging.INFO, logging.DEBUG)[min(verbose, 2)]
    for name in OWN_LOGGERS:
        logger = logging.getLogger(name)
        logger.handlers = [h for h in logger.handlers if not isinstance(h, _StderrHandler)]
        handler = _StderrHandler()
        handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
        logger.addHandler(handler)
        logger.setLevel(level)
        logger.propagate = False


def _long_names(command: click.Command) -> dict[str, str]:
    """Config keys of a command: each option's long names (without ``--``, dashes as underscores) -> its parameter.

    The ``--no-x`` side of an on/off flag is not a key (``ground = false``, not ``no-ground = true``).
    """
    names = {}
    for p in command.params:
        if isinstance(p, click.Option) and p.expose_value:
            for opt in p.opts:
                if opt.startswith("--"):
                    names[opt[2:].replace("-", "_")] = p.name
    return names


def _load_config(ctx: click.Context, _param, value: Path | None):
    """``--config FILE.toml``: every option has a key (its long name, dashes or underscores); flags override.

    Top-level keys apply to every bake command; one that this command does not
    have but another ``foliage`` command does (``resolution`` for ``smax``) is
    skipped, so one file can serve a whole pipeline. A ``[COMMAND]`` table
    applies to that command and wins; there, and for keys no command has, an
    unknown key is an error (a typo must not be silently ignored).
    """
    if value is None:
        return value
    import tomllib

    from foliage_tools.scene.dependencies import file_problem

    problem = file_problem(value)  # from stat alone: a FIFO or a device is never opened (it would block or never end)
    if problem is not None and Path(value).exists():
        raise click.BadParameter(f"@{value}@ {problem}; give an option file (TOML).", ctx=ctx, param_hint="--config")
    if problem is not None and os.path.islink(value):  # a loop, or a link to nothing
        raise click.BadParameter(f"@{value}@ {problem}.", ctx=ctx, param_hint="--config")
    try:
        data = tomllib.loads(Path(value).read_text(encoding="utf-8-sig"))  # an editor's byte-order mark is fine
    except FileNotFoundError:
        raise click.BadParameter(f"@{value}@: no such file.", ctx=ctx, param_hint="--config") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise click.BadParameter(f"@{value}@ is not valid TOML ({exc}).", ctx=ctx, param_hint="--config") from None
    except RecursionError:  # arrays or tables nested thousands deep: more than Python's parser follows
        raise click.BadParameter(f"@{value}@ nests arrays or tables too deeply to read; an option file needs at most "
                                 "one level (a [COMMAND] table).", ctx=ctx, param_hint="--config") from None
    known = _long_names(ctx.command)
    root = ctx.find_root().command
    others: set[str] = set()
    for cmd in getattr(root, "commands", {}).values():
        others.update(_long_names(cmd))
    commands = set(getattr(root, "commands", {}))
    strays = sorted(k for k, v in data.items() if isinstance(v, dict) and k not in commands)
    if strays:  # a misspelt [COMMAND] table would be skipped silently
        raise click.BadParameter(
            f"@{value}@: [{strays[0]}] is not a foliage command; a table applies to the command it names "
            f"({', '.join(sorted(commands))}).", ctx=ctx, param_hint="--config")
    own = data.get(ctx.info_name) if ctx.info_name is not None else None
    table = own if isinstance(own, dict) else {}
    entries = [(k, v, False) for k, v in data.items() if not isinstance(v, dict)] + [(k, v, True) for k, v in table.items()]
    defaults = {}
    params = {p.name: p for p in ctx.command.params if p.name}
    for key, val, in_table in entries:
        name = key.replace("-", "_")
        if name not in known:
            if not in_table and name in others:
                continue  # another command's option in the shared part of the file
            listed = ", ".join(sorted(k.replace("_", "-") for k in known))
            raise click.BadParameter(
                f"@{value}@: unknown key {key!r} for `foliage {ctx.info_name}`; known: {listed}.",
                ctx=ctx, param_hint="--config",
            )
        param = params.get(known[name])
        if param is not None:  # a bad value names the file and the key, not only the flag it stands for
            text = isinstance(param.type, click.types.StringParamType) and param.nargs == 1 and not param.multiple
            if text and isinstance(val, list) and all(isinstance(v, (int, float, str)) for v in val):
                val = ",".join(str(v) for v in val)  # sun = [45, 60]: TOML's spelling of a comma-separated value
            whole = isinstance(param.type, click.types.IntParamType)
            if whole and (isinstance(val, bool) or (isinstance(val, float) and not val.is_integer())):
                raise click.BadParameter(f"@{value}@, key {key!r}: {val!r} is not a whole number.", ctx=ctx,
                                         param_hint="--config")
            try:
                param.process_value(ctx, val)  # its type and its callback, as a flag's value would go through them
            except click.BadParameter as exc:
                where = f"key {key!r} of its [{ctx.info_name}] table" if in_table else f"top-level key {key!r}"
                hint = "" if in_table else (
                    f" A top-level key applies to every command that has it; to set it for one command, put it in "
                    f"that command's table (e.g. [{ctx.info_name}]).")
                raise click.BadParameter(f"@{value}@, {where}: {exc.format_message()}{hint}", ctx=ctx,
                                         param_hint="--config") from None
        defaults[known[name]] = val
    ctx.default_map = {**(ctx.default_map or {}), **defaults}
    ctx.meta["foliage.config"] = str(value)  # named by errors in the values it set
    if ctx.info_name == "bake":  # bake runs these stages, but with its own options: say what does not reach them
        tables = [k for k in ("density", "smax", "spp", "lb", "reference", "preview") if isinstance(data.get(k), dict)]
        skipped = sorted(k for k, v in data.items() if not isinstance(v, dict) and k.replace("-", "_") not in known)
        if tables or skipped:
            what = " and ".join(part for part in (
                f"its [{'], ['.join(tables)}] table{'s' if len(tables) > 1 else ''}" if tables else "",
                f"its top-level key{'s' if len(skipped) > 1 else ''} {', '.join(skipped)}" if skipped else "") if part)
            ctx.meta["foliage.config_warnings"] = [
                f"@{value}@: {what} did not reach `foliage bake`'s stages: bake takes its own options (the file's "
                "top level and its [bake] table); the others apply when that command runs on its own."]
    return value


def check_sun(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    """``--sun AZ,EL`` checked where it is given (a flag or a --config key, which then names the file), once for
    every command that takes it: azimuth in [0, 360) (another value is refused, naming the one it stands for),
    elevation in (0, 90] (the bakes need a sun above the horizon). Kept as text: the stages parse it
    (``geometry.sun.parse_sun``)."""
    if value is None:
        return None
    from foliage_tools.errors import UsageError
    from foliage_tools.geometry.sun import parse_sun

    try:
        az, el = parse_sun(value)
    except UsageError as exc:
        raise click.BadParameter(str(exc), ctx=ctx, param=param) from None
    given = float(str(value).split(",")[0])
    if not 0.0 <= given < 360.0:
        raise click.BadParameter(f"the azimuth must be from 0 up to 360 degrees, got {given:g} (the same direction "
                                 f"is {az:g}): give --sun {az:g},{el:g}.", ctx=ctx, param=param)
    if not 0.0 < el <= 90.0:
        raise click.BadParameter(f"the sun is at or below the horizon (elevation {el:g} degrees); the bakes need a "
                                 "sun above it: give an elevation above 0 and at most 90.", ctx=ctx, param=param)
    return value


class FiniteFloat(click.types.FloatParamType):
    """A number option that refuses nan and inf (click's FLOAT takes them, and a range passes nan)."""

    name = "number"

    def convert(self, value, param, ctx):
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number.", param, ctx)
        return number


class FiniteFloatRange(click.FloatRange):
    """:class:`click.FloatRange` that refuses nan and inf first (nan compares false, so it passes any range)."""

    def convert(self, value, param, ctx):
        FINITE_FLOAT.convert(value, param, ctx)
        return super().convert(value, param, ctx)


FINITE_FLOAT = FiniteFloat()


def finite_floats(group: click.Group) -> None:
    """Every float option of every command of ``group`` refuses nan and inf at the option (a flag, a --config key,
    a batch manifest's key), with click's message naming it: the one place, so a new option cannot forget."""
    for command in group.commands.values():
        for param in command.params:
            kind = param.type
            if type(kind) is click.FloatRange:
                param.type = FiniteFloatRange(kind.min, kind.max, min_open=kind.min_open, max_open=kind.max_open,
                                              clamp=kind.clamp)
            elif type(kind) is click.types.FloatParamType:
                param.type = FINITE_FLOAT


class _SeedRange(click.IntRange):
    """A random seed, 0 to 2**63 - 1: USD stores it as a 64-bit signed integer (its help says so in short)."""

    def _describe_range(self) -> str:
        return "0<=x<2**63"


SEED = _SeedRange(0, 2**63 - 1)


def config_option(fn: Callable) -> Callable:
    """``--config FILE.toml`` (``_load_config``): the bake commands, density, plan and preview."""
    return click.option(
        "--config", type=click.Path(path_type=Path, dir_okay=False), callback=_load_config, is_eager=True, expose_value=False,
        help="TOML file of option values; flags win.",
    )(fn)


def bake_options(fn: Callable) -> Callable:
    """Options shared by the bake commands (DESIGN.md section 3)."""
    fn = config_option(fn)
    fn = click.option("--wood-reflectance", type=click.FloatRange(0, 1), default=None, help="Bark reflectance, 0 to 1 [default: 0.2].")(fn)
    fn = click.option(
        "--leaf-optics", default=None, metavar="PRESET|r,t|rR,rG,rB,tR,tG,tB",
        help="Leaf reflectance,transmittance: a preset (geist2008, bright), r,t, or RGB each [default: geist2008].",
    )(fn)
    fn = click.option(
        "--sun", default=None, metavar="AZ,EL", callback=check_sun,
        help="Sun azimuth,elevation, degrees [default: stage's sun or 45,60].",
    )(fn)
    return fn


def direct_options(fn: Callable) -> Callable:
    """``--direct`` and ``--direct-samples``: the E_direct a bake writes (shared by lb, spp, smax and bake)."""
    fn = click.option(
        "--direct-samples", default="auto", show_default=True, callback=parse_direct_samples, metavar="auto|N",
        help="With --direct rays: shadow rays per leaf, an even number. auto: 1024 up to 16k leaves, fewer above "
             "(at most 16M rays in all).",
    )(fn)
    fn = click.option(
        "--direct", "direct_mode", type=click.Choice(["rays", "volume"]), default="rays", show_default=True,
        help="E_direct per leaf (primvars:foliage:<m>:direct). rays: exact, shadow rays through every leaf and wood "
             "triangle; volume: the method's own volume estimate, as in its paper.",
    )(fn)
    return fn


def grid_precision_option(fn: Callable) -> Callable:
    """``--grid-precision`` (lb, bake): how the LB grids are stored on disk (``LBBakeParams.grid_precision``)."""
    return click.option(
        "--grid-precision", type=click.Choice(["float", "half"]), default="float", show_default=True,
        help="How the LB grids are stored in the .vdb: float (float32) or half (half the file, each value within "
             "2^-11 relative). Other grids stay float.",
    )(fn)


def volume_purpose_option(fn: Callable) -> Callable:
    """``--volume-purpose`` (density, spp, lb, bake): the purpose of the FoliageLighting volume written."""
    return click.option(
        "--volume-purpose", type=click.Choice(["default", "guide"]), default="default", show_default=True,
        help="Purpose of the <tree>/FoliageLighting volume: default (DCCs import and draw it) or guide (kept out of "
             "default imports and renders).",
    )(fn)


def gather_option(later_bounces: str, replaces: str) -> Callable:
    """``--gather auto|N`` (lb, spp, bake): a final gather over the actual leaves on top of the volume method."""
    return click.option(
        "--gather", default="auto", show_default=True, callback=parse_gather, metavar="auto|N",
        help="Final gather: N rays per leaf (a multiple of 4) through the actual leaves, the first bounce exact, "
             f"{later_bounces} for the later ones; replaces {replaces}. auto: 1024 up to 16k leaves, fewer above, "
             "off above 262k leaves and for lb --bases all; 0: off.",
    )


def _auto_or_whole(value, ctx: click.Context, param: click.Parameter) -> int | None:
    """None for ``auto`` (or no value), else the whole number the flag's text gives."""
    if value is None or str(value).strip().lower() == "auto":
        return None
    try:
        return int(str(value).strip())
    except ValueError:
        raise click.BadParameter(f"{value!r} is neither 'auto' nor a whole number.", ctx=ctx, param=param) from None


def parse_depth_resolution(ctx: click.Context, param: click.Parameter, value) -> int | None:
    """``--depth-resolution auto|N`` (spp): None for auto, else N voxels (``SppParams`` checks the range)."""
    return _auto_or_whole(value, ctx, param)


def parse_gather(ctx: click.Context, param: click.Parameter, value) -> int | None:
    k = _auto_or_whole(value, ctx, param)
    if k is not None and k < 0:
        raise click.BadParameter(f"{k}: give 'auto', 0 (off) or a number of rays per leaf (a multiple of 4).",
                                 ctx=ctx, param=param)
    return k


def parse_direct_samples(ctx: click.Context, param: click.Parameter, value) -> int | None:
    k = _auto_or_whole(value, ctx, param)
    if k is None:
        return None
    from foliage_tools.lighting.direct import MAX_SAMPLES

    if k < 2 or k % 2 or k > MAX_SAMPLES:
        raise click.BadParameter(f"{k} must be even, from 2 (two halves give the sampling error) to {MAX_SAMPLES}.",
                                 ctx=ctx, param=param)
    return k


def direct_choice(mode: str, samples: int | None):
    from foliage_tools.pipeline.direct import DirectChoice

    return DirectChoice(mode=mode, samples=samples)


def leaf_optics_from_flags(leaf_optics: str | None, wood_reflectance: float | None):
    from foliage_tools.errors import UsageError
    from foliage_tools.lighting.optics import parse_leaf_optics

    try:
        return parse_leaf_optics(leaf_optics, wood_reflectance=wood_reflectance)
    except ValueError as exc:
        msg = str(exc)
        if not msg.startswith("--leaf-optics"):  # a range error of the values: name the flag and what was given
            msg = f"--leaf-optics {leaf_optics!r}: {msg}"
        ctx = click.get_current_context(silent=True)
        if ctx is not None and ctx.get_parameter_source("leaf_optics") == click.core.ParameterSource.DEFAULT_MAP:
            msg = f"@{ctx.meta.get('foliage.config', 'the --config file')}@, key leaf-optics: {msg}"
        raise UsageError(msg) from None


def _label_sun(stats, source: str) -> None:
    """Every ``{"sun": {"source": "--sun"}}`` in a report's stats (a bake's stages too) says the sun came from
    the config file: the stages see a --sun value either way."""
    if isinstance(stats, dict):
        sun = stats.get("sun")
        if isinstance(sun, dict) and sun.get("source") == "--sun":
            sun["source"] = source
        for value in stats.values():
            _label_sun(value, source)


def config_notes(report) -> None:
    """What ``--config`` could not apply (``_load_config``) among ``report``'s warnings, and a sun the file set
    reported as from it."""
    ctx = click.get_current_context(silent=True)
    if ctx is None:
        return
    report.warnings = [*ctx.find_root().meta.get("foliage.config_warnings", []), *report.warnings]
    if "sun" in ctx.params and ctx.get_parameter_source("sun") == click.core.ParameterSource.DEFAULT_MAP:
        _label_sun(report.stats, f"--config {ctx.meta.get('foliage.config', '')}".strip())


def execute(stage: Callable[[Progress], Report[S]], *, as_json: bool, quiet: bool,
            render: Callable[[Report[S]], object] | None = None) -> int:
    """Run ``stage(progress) -> Report`` with a progress bar, then print its JSON, or warnings, ``render(report)`` and
    outputs. The folders of the command's ``-o`` files are made first (:func:`output_folders`)."""
    ctx = click.get_current_context(silent=True)
    folders = list(ctx.meta.get(OUTPUT_FOLDERS, [])) if ctx is not None else []
    with output_folders(folders), console.RichProgress(enabled=not (quiet or as_json)) as progress:
        report = stage(progress)
    config_notes(report)
    if as_json:
        console.print_json(report.as_json())
    else:
        console.warn(report.warnings, quiet)
        if not quiet:
            if render is not None:
                render(report)
            for o in report.outputs:
                console.stdout.print(f"wrote {o}", highlight=False, soft_wrap=True)
    if report.findings:  # the outputs are written, but the bake failed its own accuracy check (DESIGN.md section 3)
        for f in report.findings:
            console.error(f, "accuracy check failed")
        return EXIT_FINDINGS
    return 0
