"""Atomic output: the files of one result become visible together, or not at all.

A result (a stage's layer and its ``.vdb`` grids, or every file of a
``foliage bake``) is written into a hidden *staging directory* inside the
output directory itself, ``.LABEL.tmp-PID-TOKEN`` (beside the outputs, so the
final renames never cross a device: an output directory that is a mount point
works). When every file is complete, :meth:`Commit.commit`

0. checks that every staged file is whole (:func:`check_written`: not cut at
   the file-size limit, and read back as what its extension says);
1. refuses, before anything moves, a final name that is a directory, and
   starts no commit once the run has been interrupted
   (``foliage_tools.interrupts``);
2. writes a journal (``.commit``, the list of names) into the staging
   directory: from then on the new result is the result;
3. renames the files into place, grids before the layers that refer to them,
   with SIGINT, SIGTERM and SIGHUP held back until the last rename is done;
4. removes the journal and the staging directory.

POSIX cannot rename several files at once, so a process killed outright
(SIGKILL, power loss) between two renames of step 3 leaves a mix of old and
new files. Two things make that safe: the layers record the content hash of
every grid file and upstream layer they were written with (``scene.integrity``),
so ``validate`` and every stage reading the result refuse the mix and name the
stale file; and the journal lets the next run on the same output finish the
renames (:func:`recover`), which also removes the staging directories of
runs that died before step 2. Recovery follows only what a commit writes
(:func:`staged_names`: plain file names, no symbolic links), so a planted
journal cannot move anything else. Commits into one directory are serialised
by a lock on the directory, so two concurrent writers of one output cannot
interleave their renames; :func:`run_lock` keeps a second run off a result
for the whole of the first (``bake``).

Test hook: :data:`before_rename` (a callable) and the environment variable
``FOLIAGE_TEST_KILL_AT_RENAME=N[:SIGNAL]`` (the process sends itself SIGNAL,
default KILL, just before rename number N, counted from 0 within a commit)
are checked before every rename of step 3 (of commits into a directory that
is not itself a staging directory: the commits of ``bake``'s stages into its
staging directory are invisible outside, and not counted).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import os
import re
import resource
import secrets
import shutil
import signal
import socket
import stat
import tempfile
import threading
import time
from pathlib import Path
from types import FrameType
from typing import Any, Callable, Iterable, Iterator

from foliage_tools.errors import OutputError
from foliage_tools.interrupts import INTERRUPT_SIGNALS, interrupt_noted

JOURNAL = ".commit"
"""In a staging directory: the names to move into place, one a line, in order (present = committed)."""
OWNER = ".owner"
"""In a staging directory: ``HOST PID`` of the run that made it."""
KILL_ENV = "FOLIAGE_TEST_KILL_AT_RENAME"

#: Test hook: called as ``before_rename(index, staged_path, final_path)`` before each rename of a commit.
before_rename: Callable[[int, Path, Path], None] | None = None

#: How long a commit waits for another run's commit into the same directory (seconds; commits take milliseconds).
LOCK_TIMEOUT = 60.0

_LABEL_MAX = 100  # keeps ``.LABEL.tmp-PID-TOKEN`` within NAME_MAX (255) whatever the output name
_STAGING = re.compile(r"\.(?P<label>.+)\.tmp-(?P<pid>\d+)-(?P<token>[0-9a-f]+)")


class InterruptedAfterCommit(KeyboardInterrupt):
    """An interrupt that arrived during a commit: it was held back, and the result is complete in place."""

    def __init__(self, paths: list[Path]) -> None:
        super().__init__(f"interrupted after writing {', '.join(str(p) for p in paths)}")
        self.paths = paths


def staging_label(name: str) -> str:
    """The LABEL of a staging directory for an output named ``name`` (shortened with a hash when long)."""
    if len(name.encode()) <= _LABEL_MAX:
        return name
    return name[:60] + "~" + hashlib.sha1(name.encode()).hexdigest()[:12]


def temp_sibling(path: Path) -> Path:
    """The temporary name earlier versions wrote ``path`` under (``.STEM.tmp-PID.EXT``): :func:`recover` removes them."""
    return path.with_name(f".{path.stem}.tmp-{os.getpid()}{path.suffix}")


def check_writable(path: Path) -> None:
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.exists():
        raise OutputError(f"@{path}@: the directory {parent} does not exist; create it first.")
    check_name_fits(path)
    if path.is_dir():
        raise OutputError(f"@{path}@ is a directory; give a file name.")
    # os.access says yes to root on read-only mounts and special filesystems: try it for real
    try:
        with tempfile.NamedTemporaryFile(dir=parent, prefix=".foliage-probe-"):
            pass
    except OSError as exc:
        raise OutputError(f"@{path}@: the directory {parent} is not writable ({exc.strerror}); choose another output path.") from None


def check_name_fits(path: Path) -> None:
    """Refuse a file name longer than its filesystem allows (ENAMETOOLONG), or one that is a symbolic link that
    loops (which no path check could resolve), before any work."""
    refuse_link_loop(path)
    parent = path.parent if str(path.parent) else Path(".")
    try:
        limit = os.pathconf(parent, "PC_NAME_MAX")
    except (OSError, ValueError):
        limit = 255
    size = len(path.name.encode())
    if size > limit:
        raise OutputError(
            f"@{path}@: the file name is {size} bytes long and this filesystem allows {limit}; choose a shorter output name."
        )


def refuse_link_loop(path: Path) -> None:
    """:class:`OutputError` when the output name ``path`` (or a folder above it) is a symbolic link that loops."""
    try:
        os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise OutputError(f"@{path}@ is a symbolic link that loops (it never reaches a file); remove it "
                              f"(rm '{path}') or choose another output path.") from None


def _alive(pid: int) -> bool:
    """Whether ``pid`` is a live process of this host (a number outside the platform's pid range is none)."""
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, OverflowError):
        return False
    except PermissionError:  # someone else's process
        return True
    return True


@contextlib.contextmanager
def _interrupts_held() -> Iterator[list[tuple[int, FrameType | None]]]:
    """Hold SIGINT/SIGTERM/SIGHUP back; one that arrived meanwhile is handled (and raises) when the block ends.

    Done at Python level, by swapping the handlers: blocking the signals in
    this thread would not do, since the kernel then hands a process-wide
    signal to one of the library threads (TBB, numba) and Python still runs
    the handler here at once. Signals without a Python handler (the default
    action, ignored) are left as they are; only the main thread can swap
    handlers, so elsewhere nothing is held back.
    """
    caught: list[tuple[int, FrameType | None]] = []
    if threading.current_thread() is not threading.main_thread():
        yield caught
        return
    previous: dict[int, Callable[[int, FrameType | None], Any]] = {}
    for sig in INTERRUPT_SIGNALS:
        handler = signal.getsignal(sig)
        if callable(handler):
            previous[sig] = handler
            signal.signal(sig, lambda signum, frame: caught.append((signum, frame)))
    try:
        yield caught
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        if caught:
            signum, frame = caught[0]
            previous[signum](signum, frame)


@contextlib.contextmanager
def _directory_lock(directory: Path) -> Iterator[None]:
    """An exclusive lock on ``directory`` for the length of a commit (no lock where the filesystem has none)."""
    try:
        fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
    except OSError:
        yield
        return
    try:
        deadline = time.monotonic() + LOCK_TIMEOUT
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    raise OutputError(
                        f"@{directory}@: another run has been moving its results into this directory for "
                        f"{LOCK_TIMEOUT:.0f} s; is a foliage process stopped there? Try again when it has finished."
                    ) from None
                time.sleep(0.05)
            except OSError:  # e.g. NFS without flock on directories: commits are not serialised there
                break
        yield
    finally:
        os.close(fd)


LOCK_SUFFIX = ".lock"
"""``.LABEL.lock`` in an output directory: held by the one run writing the result LABEL there (:func:`run_lock`)."""


@contextlib.contextmanager
def run_lock(directory: Path, label: str) -> Iterator[None]:
    """Hold the result ``label`` in ``directory`` for one run, from its checks to its commit; refuse a second.

    A second run writing the same result into the same directory at the same
    time is refused at once (:class:`OutputError`, exit 2, naming the run that
    holds it), not made to wait: its result would replace the first one's, so
    two pipeline steps writing one output is a mistake to fix, and a step that
    waited silently could wait for hours. Results of other names in the same
    directory do not wait for each other. The lock is ``flock`` on
    ``.LABEL.lock``, removed when the run ends (the kernel drops the lock of
    a killed run; its file is then reused). Where the filesystem has no
    ``flock``, nothing is locked.
    """
    path = Path(directory) / f".{staging_label(label)}{LOCK_SUFFIX}"
    fd, made, locked = -1, False, False
    try:  # one try from the first open on: an interrupt anywhere in here leaves no lock file of this run's behind
        while True:
            try:
                try:
                    fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o644)
                    made = True
                except FileExistsError:
                    _refuse_odd_lock(path, os.lstat(path))  # before opening: a device or FIFO is not even opened
                    fd = os.open(path, os.O_RDWR | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK)
                    _refuse_odd_lock(path, os.fstat(fd))  # what was opened: not swapped in between
            except OSError as exc:
                if exc.errno == errno.ELOOP:
                    raise OutputError(f"@{path}@ is a symbolic link, where this run keeps its lock; a foliage run "
                                      f"never makes one: remove it (rm '{path}') and run the command again.") from None
                if exc.errno == errno.ENOENT:  # removed between the two opens by the run that held it: again
                    continue
                break  # an unwritable directory: the run's own checks say so
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                made = False  # another run locked it, even if this one created it: it is that run's to remove
                try:
                    owner = os.read(fd, 256).decode("utf-8", "replace").split()
                except OSError:
                    owner = []
                who = f"process {owner[1]} on {owner[0]}" if len(owner) == 2 else "another process"
                raise OutputError(
                    f"@{Path(directory) / label}@: another foliage run ({who}) is writing this result into {directory} "
                    "now; wait for it to finish, or write into another directory. Nothing was written.") from None
            except OSError:  # e.g. NFS without flock: nothing is locked
                break
            locked = True
            try:  # the run that held it may have removed the file meanwhile (and a third locked a new one): again
                same = os.stat(path, follow_symlinks=False).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            locked = made = False
            os.close(fd)
            fd = -1
        if locked:  # into a file this run created, or one verified a lone regular file (_refuse_odd_lock)
            with contextlib.suppress(OSError):
                os.ftruncate(fd, 0)
                os.write(fd, f"{socket.gethostname()} {os.getpid()}\n".encode())
        yield
    finally:
        if locked or made:
            with contextlib.suppress(OSError):
                os.unlink(path)
        if fd >= 0:
            os.close(fd)


def _refuse_odd_lock(path: Path, st: os.stat_result) -> None:
    """A lock file a foliage run made is a regular file with one link: anything else (a hard link to another file,
    a FIFO, a device) is not written into, but refused (:class:`OutputError`)."""
    if stat.S_ISLNK(st.st_mode):
        return  # opening it with O_NOFOLLOW fails (ELOOP), and says so
    if not stat.S_ISREG(st.st_mode) or st.st_nlink > 1:
        what = "is not a regular file" if not stat.S_ISREG(st.st_mode) else f"has {st.st_nlink} hard links"
        raise OutputError(
            f"@{path}@ {what}, where this run keeps its lock; a foliage run never makes one, so nothing was written "
            f"into it: remove it (rm '{path}') and run the command again.")


def _fsync(path: Path, directory: bool = False) -> None:
    try:
        fd = os.open(path, os.O_RDONLY | (os.O_DIRECTORY if directory else 0))
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _kill_hook(index: int) -> None:
    spec = os.environ.get(KILL_ENV)
    if not spec:
        return
    at, _, name = spec.partition(":")
    if int(at) == index:
        os.kill(os.getpid(), getattr(signal, f"SIG{name or 'KILL'}"))


def _move(directory: Path, staging: Path, names: list[str]) -> list[Path]:
    """Step 3: rename ``names`` from ``staging`` into ``directory`` in order (the test hooks run before each)."""
    done: list[Path] = []
    visible = not _STAGING.fullmatch(directory.name)  # not a commit inside another result's staging directory
    for i, name in enumerate(names):
        src, dst = staging / name, directory / name
        if visible:
            if before_rename is not None:
                before_rename(i, src, dst)
            _kill_hook(i)
        try:
            os.replace(src, dst)
        except OSError as exc:
            left = [n for n in names if n not in {p.name for p in done}]
            raise OutputError(
                f"@{dst}@: cannot be moved into place ({exc.strerror}) after {len(done)} of {len(names)} files of the "
                f"result were; {', '.join(left)} are still in @{staging}@. Fix the cause and run the command again: "
                "it finishes this result first, then writes its own."
            ) from None
        done.append(dst)
    return done


def file_size_limit() -> int | None:
    """This process's file-size limit in bytes (``ulimit -f``, RLIMIT_FSIZE); None when there is none."""
    soft, _ = resource.getrlimit(resource.RLIMIT_FSIZE)
    return None if soft == resource.RLIM_INFINITY else int(soft)


def _size_limit_error(final: Path, size: int | None = None) -> OutputError:
    limit = file_size_limit()
    cut = f"was cut at {size:,} bytes: " if size is not None else "cannot be written whole: "
    what = f"{limit:,} bytes" if limit is not None else "set"
    return OutputError(
        f"@{final}@ {cut}the file-size limit of this process (ulimit -f, RLIMIT_FSIZE) is {what}. Raise it "
        "(`ulimit -f unlimited`) or write a smaller result, and run the command again. Nothing was written: an earlier "
        "result there is left as it was."
    )


def _read_back(path: Path) -> str | None:
    """Why the file at ``path`` does not read back whole as what its extension says (None: it does)."""
    suffix = path.suffix.lower()
    try:
        if suffix == ".vdb":
            from foliage_tools.scene.vdb import unreadable_grids

            return unreadable_grids(path)
        if suffix in (".usda", ".usdc", ".usd"):
            from pxr import Sdf

            if Sdf.Layer.OpenAsAnonymous(str(path)) is None:
                return "USD cannot open it"
        elif suffix in (".png", ".exr"):
            import OpenImageIO as oiio

            inp = oiio.ImageInput.open(str(path))
            if inp is None:
                return oiio.geterror() or "not an image"
            try:
                if inp.read_image() is None:
                    return inp.geterror() or "its pixels cannot be read"
            finally:
                inp.close()
        elif suffix == ".json":
            import json

            json.loads(path.read_text(encoding="utf-8"))
    except Exception as exc:  # the readers raise assorted types for a cut file
        return _short(exc)
    return None


def check_written(path: Path, final: Path, *, read_back: bool = True) -> None:
    """Before a commit: the file staged at ``path`` (for ``final``) is whole.

    A write past the file-size limit (``ulimit -f``) fails with EFBIG (Python
    ignores SIGXFSZ), which OpenVDB's and OpenImageIO's writers do not all
    report: the file is then exactly as long as the limit. A file that long,
    or one that does not read back as what its extension says (a ``.vdb``
    whose grids all read, a layer USD opens, an image whose pixels read), is
    refused (:class:`OutputError`), so it never replaces an earlier result.
    ``read_back=False``: a copy of another file (``Commit.copies``), which is
    not what its extension says by our writing, and which the copy itself
    checked (``shutil`` raises on a short write).
    """
    st = os.lstat(path)
    if not stat.S_ISREG(st.st_mode):
        raise OutputError(f"@{final}@: what was staged for it is not a regular file (a symbolic link?); nothing was written.")
    size = st.st_size
    limit = file_size_limit()
    if limit is not None and size >= limit:
        raise _size_limit_error(final, size)
    problem = _read_back(path) if read_back else None
    if problem is not None:
        raise OutputError(
            f"@{final}@: the file just written does not read back whole ({problem}), so it was not moved into place: "
            "check the disk and the limits of this process (`ulimit -a`) and run the command again. Nothing was "
            "written: an earlier result there is left as it was."
        )


class Commit:
    """Files that become visible together in ``directory`` (module docstring).

    Write each file to :meth:`path` (its final name inside the staging
    directory), then call :meth:`commit`; :meth:`discard` (or leaving a
    ``with`` block by an exception) removes the staging directory.
    """

    def __init__(self, directory: Path, name: str) -> None:
        self.directory = Path(directory)
        self.name = name
        #: Names staged as copies of other files (``bake --portable``'s copies of the input's textures): checked
        #: against the file-size limit before the commit, not read back as what their extension says.
        self.copies: set[str] = set()
        self.staging: Path | None = self.directory / f".{staging_label(name)}.tmp-{os.getpid()}-{secrets.token_hex(4)}"
        try:
            self.staging.mkdir()
            (self.staging / OWNER).write_text(f"{socket.gethostname()} {os.getpid()}\n", encoding="utf-8")
        except KeyboardInterrupt:  # nobody else will remove it: the caller never gets this Commit
            shutil.rmtree(self.staging, ignore_errors=True)
            raise
        except OSError as exc:
            shutil.rmtree(self.staging, ignore_errors=True)
            raise OutputError(
                f"@{self.directory / name}@: cannot write in {self.directory} ({exc.strerror}); "
                "choose another output path. Nothing was written."
            ) from None
        self.committed: list[Path] | None = None

    def __enter__(self) -> "Commit":
        return self

    def __exit__(self, *exc) -> None:
        self.discard()

    def path(self, name: str) -> Path:
        assert self.staging is not None, "the commit is already done or discarded"
        return self.staging / name

    def files(self) -> list[str]:
        """The names staged so far (hidden entries are the commit's own)."""
        assert self.staging is not None, "the commit is already done or discarded"
        return sorted(p.name for p in self.staging.iterdir()
                      if not p.name.startswith(".") and stat.S_ISREG(os.lstat(p).st_mode))

    def commit(self, names: Iterable[str]) -> list[Path]:
        """Move ``names`` into place together (module docstring, steps 1-4); the final paths, in order."""
        names = list(names)
        staging = self.staging
        assert staging is not None, "the commit is already done or discarded"
        missing = [n for n in names if not (staging / n).is_file()]
        if missing:
            raise ValueError(f"not staged: {missing}")
        for n in names:
            _fsync(staging / n)
        # a commit into another result's staging directory (a bake's stage) names the file by its final place
        where = self.directory.parent if _STAGING.fullmatch(self.directory.name) else self.directory
        for n in names:
            check_written(staging / n, where / n, read_back=n not in self.copies)
        try:
            return self._commit(names)
        except KeyboardInterrupt as exc:
            # a commit into another result's staging directory (a bake's stage) is not a result anyone sees: the
            # enclosing run removes it, so its interrupt is a plain one
            visible = not _STAGING.fullmatch(self.directory.name)
            if visible and self.committed is not None and not isinstance(exc, InterruptedAfterCommit):
                raise InterruptedAfterCommit(self.committed) from None
            raise

    def _commit(self, names: list[str]) -> list[Path]:
        assert self.staging is not None, "the commit is already done or discarded"
        with _directory_lock(self.directory), _interrupts_held() as caught:
            noted = caught[0][0] if caught else interrupt_noted()
            if noted is not None:
                # the run was interrupted (its KeyboardInterrupt may have been lost on the way, in a library's
                # callback or cleanup): nothing is committed after that
                raise KeyboardInterrupt(signal.Signals(noted).name)
            for n in names:
                final = self.directory / n
                if final.is_dir() and not final.is_symlink():
                    raise OutputError(
                        f"@{final}@ is a directory, where this run writes its file {n}; remove or rename it, or choose "
                        "another output. Nothing was written."
                    )
            journal = self.staging / JOURNAL
            tmp = self.staging / (JOURNAL + ".tmp")
            tmp.write_text("".join(f"{n}\n" for n in names), encoding="utf-8")
            _fsync(tmp)
            os.replace(tmp, journal)
            _fsync(self.staging, directory=True)
            try:
                finals = _move(self.directory, self.staging, names)
            except BaseException:
                self.staging = None  # the journal stays, for the next run to finish (module docstring)
                raise
            _fsync(self.directory, directory=True)
            self.committed = finals
            shutil.rmtree(self.staging, ignore_errors=True)
            self.staging = None
        return finals

    def discard(self) -> None:
        if self.staging is not None:
            shutil.rmtree(self.staging, ignore_errors=True)
            self.staging = None


def _disk_full(directory: Path, exc: BaseException) -> bool:
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return True
    if "no space left" in str(exc).lower():
        return True
    try:
        st = os.statvfs(directory)
    except OSError:
        return False
    return st.f_bavail * st.f_frsize < 64 * 1024


def _short(exc: BaseException) -> str:
    """One line of an error: USD's and OpenVDB's chain several ``Error in '...' at line N ...: 'what'`` lines."""
    lines = [line.strip() for line in str(exc).strip().splitlines() if line.strip()]
    if not lines:
        return type(exc).__name__
    pick = next((line for line in lines if "space" in line.lower()), lines[-1])
    m = re.search(r": '(.*)'$", pick)
    return m.group(1) if m else pick


@contextlib.contextmanager
def atomic_outputs(paths: list[Path]) -> Iterator[dict[Path, Path]]:
    """Yield {final path: staged path}; when the block ends without an error, move them all into place together.

    The files must share one directory. They are renamed in the order given,
    so list the files a layer refers to (``.vdb``) before the layer itself;
    paths the block did not write are left alone. On an error the staged files
    are removed and nothing is written.
    """
    paths = [Path(p) for p in paths]
    directories = {p.parent for p in paths}
    if len(directories) != 1:
        raise ValueError(f"atomic outputs must share one directory, got {sorted(map(str, directories))}")
    directory = directories.pop()
    commit = Commit(directory if str(directory) else Path("."), paths[-1].name)
    try:
        yield {p: commit.path(p.name) for p in paths}
        commit.commit([p.name for p in paths if commit.path(p.name).exists()])
    except OutputError:
        raise
    except Exception as exc:
        if isinstance(exc, OSError) and exc.errno == errno.EFBIG:
            raise _size_limit_error(Path(exc.filename) if exc.filename else paths[-1]) from None
        if commit.staging is not None and _disk_full(commit.staging, exc):
            raise OutputError(
                f"@{paths[-1]}@: the disk holding {directory} is full ({_short(exc)}); free some space or choose another "
                "output path. Nothing was written."
            ) from None
        if isinstance(exc, OSError):
            raise OutputError(
                f"@{exc.filename or paths[-1]}@: cannot be written ({exc.strerror}); nothing was written."
            ) from None
        raise
    finally:
        commit.discard()


def _plain_name(name: str) -> bool:
    """A name a commit can stage: one path component (no ``/``, neither ``.`` nor ``..``, no NUL), and none of the
    names this module keeps for itself (the journal, the owner, staging folders, locks). An output named with a
    leading dot (``-o .x.usda``) is a plain name too: it stays inside the directory like any other."""
    if not name or "/" in name or "\0" in name or name in (".", ".."):
        return False
    return name not in (JOURNAL, JOURNAL + ".tmp", OWNER) and not _STAGING.fullmatch(name) and not name.endswith(LOCK_SUFFIX)


def _refuse(staging: Path, why: str) -> OutputError:
    return OutputError(
        f"@{staging}@ looks like a foliage staging folder, but {why}; a foliage run never leaves that, so nothing "
        f"was moved or removed. Look at what it holds, then remove it (rm -r '{staging}') and run the command again."
    )


def _lstat(path: Path) -> os.stat_result | None:
    try:
        return os.lstat(path)
    except FileNotFoundError:
        return None


def staged_names(staging: Path) -> list[str] | None:
    """The names the journal of ``staging`` lists (None: no journal, the run died before its commit).

    Only what a commit writes is accepted (:class:`OutputError` otherwise,
    naming the folder): ``staging`` a real directory (not a symbolic link),
    its journal a regular file, each name in it a plain file name (no ``/``,
    not hidden, so no ``..``) and each staged file still there a regular
    file. A recovery that follows it then only moves files the journal's own
    run staged, to names in the directory that holds ``staging``.
    """
    st = _lstat(staging)
    if st is None:
        return None
    if not stat.S_ISDIR(st.st_mode):
        raise _refuse(staging, "it is a symbolic link or not a directory")
    journal = staging / JOURNAL
    jst = _lstat(journal)
    if jst is None:
        return None
    if not stat.S_ISREG(jst.st_mode):
        raise _refuse(staging, f"its journal {JOURNAL} is not a regular file")
    try:
        text = journal.read_text(encoding="utf-8")
    except FileNotFoundError:  # its run finished meanwhile
        return None
    except UnicodeDecodeError:
        raise _refuse(staging, f"its journal {JOURNAL} is not text") from None
    except OSError as exc:
        raise _refuse(staging, f"its journal {JOURNAL} cannot be read ({exc.strerror})") from None
    names = [n for n in text.split("\n") if n]
    for n in names:
        if not _plain_name(n):
            raise _refuse(staging, f"its journal names {n!r}, which is not a file name inside {staging.parent}")
        nst = _lstat(staging / n)
        if nst is not None and not stat.S_ISREG(nst.st_mode):
            raise _refuse(staging, f"its {n!r} is a symbolic link or not a regular file")
    return names


def own_names(names: Iterable[str], allow: Callable[[str], bool] | None = None) -> Callable[[str], bool]:
    """Whether a name is one a command with the planned outputs ``names`` writes: one of them, a grid file of a
    layer among them (``OUT.vdb``, ``OUT.forest.vdb``, ``OUT.NN_name.vdb``: ``pipeline.density.vdb_path``), or
    one ``allow`` accepts."""
    planned = set(names)
    stems = [Path(n).stem for n in planned if Path(n).suffix in (".usda", ".usdc", ".usd", ".vdb")]
    grids = re.compile(rf"(?:{'|'.join(map(re.escape, stems))})(?:\.forest|\.\d\d_[A-Za-z0-9_]+)?\.vdb") if stems else None

    def own(name: str) -> bool:
        return (name in planned or bool(grids and grids.fullmatch(name)) or (allow is not None and allow(name)))

    return own


def _own_journal(staging: Path, own: Callable[[str], bool]) -> list[str] | None:
    """:func:`staged_names`, refusing a journal that names a file the command does not write (the input, another
    result's file, ...): a foliage run only ever journals its own outputs."""
    names = staged_names(staging)
    for n in names or []:
        if not own(n):
            raise OutputError(
                f"@{staging}@ looks like a foliage staging folder of this output, but its journal {JOURNAL} names "
                f"{n!r}, which is not a file this command writes; a foliage run never leaves that, so nothing was "
                f"moved or removed. Look at what it holds, then remove it (rm -r '{staging}') and run the command "
                "again.")
    return names


def _owner(staging: Path) -> tuple[str, int | None]:
    """(host, pid) of the run that made ``staging`` as its ``.owner`` says; this host and None where it says nothing."""
    path = staging / OWNER
    st = _lstat(path)
    if st is None:
        return socket.gethostname(), None
    if not stat.S_ISREG(st.st_mode):
        raise _refuse(staging, f"its {OWNER} is a symbolic link or not a regular file")
    try:
        host, pid = path.read_text(encoding="utf-8").split()
        return host, int(pid)
    except (OSError, ValueError):
        return socket.gethostname(), None


def recover(directory: Path, names: Iterable[str], warnings: list[str], *, label: str | None = None,
            allow: Callable[[str], bool] | None = None) -> None:
    """Finish or remove what killed runs left behind for the outputs ``names`` in ``directory``.

    A staging directory (module docstring) whose run is no longer alive is
    finished if it holds a journal (its result was committed: the remaining
    renames are done) and removed otherwise; so are the ``.STEM.tmp-PID.EXT``
    temporaries of earlier versions. Each action is noted in ``warnings``.
    Runs still alive are left alone, and so are the staging directories of
    runs on another host (this host cannot tell whether they are alive), with
    a warning naming the host. Only what :func:`staged_names` accepts is
    followed, and a journal is followed only when every name in it is one
    this command writes (:func:`own_names`: ``names``, the grid files of a
    layer among them, and what ``allow`` accepts): anything else is refused
    (:class:`OutputError`) before anything moves. ``label``: the LABEL of the
    command's staging folders when it is not one of ``names`` (``bake``'s).
    """
    directory = Path(directory)
    names = list(names)
    labels = {staging_label(n) for n in names} | ({staging_label(label)} if label else set())
    own = own_names(names, allow)
    stems = "|".join(re.escape(Path(n).stem) for n in names)
    legacy = re.compile(rf"\.(?:{stems})(?:\.\d\d_[A-Za-z0-9_]+)?\.tmp-(?P<pid>\d+)\.(?:vdb|usda|usdc|usd|png|exr|json|svg|pdf)")
    try:
        entries = list(directory.iterdir()) if labels else []
    except OSError:
        return
    stale = []
    here = socket.gethostname()
    for entry in entries:
        m = _STAGING.fullmatch(entry.name)
        st = _lstat(entry)
        if st is None:
            continue
        if m and m["label"] in labels:
            _own_journal(entry, own)  # refuses a symbolic link, a planted journal, ... whoever it claims to be
            if not stat.S_ISDIR(st.st_mode):
                continue
            host, _ = _owner(entry)
            pid = int(m["pid"])
            if host != here:
                warnings.append(
                    f"@{entry}@ was left by a foliage run on the host {host} (process {pid}), which this host cannot "
                    f"check, so it is left as it is; once no foliage run on {host} writes into {directory}, remove it "
                    f"(rm -r '{entry}').")
            elif not _alive(pid):
                stale.append((entry, pid))
        elif (lm := legacy.fullmatch(entry.name)) and stat.S_ISREG(st.st_mode):
            pid = int(lm["pid"])
            if not _alive(pid):
                stale.append((entry, pid))
        elif entry.name.endswith(LOCK_SUFFIX) and entry.name[1:-len(LOCK_SUFFIX)] in labels and stat.S_ISREG(st.st_mode):
            _remove_stale_lock(entry)
    if not stale:
        return
    with _directory_lock(directory), _interrupts_held():
        for entry, pid in stale:
            st = _lstat(entry)
            if st is None:  # another run cleaned it meanwhile
                continue
            if stat.S_ISREG(st.st_mode):
                entry.unlink(missing_ok=True)
                warnings.append(f"removed @{entry}@, a temporary file left by an interrupted run (process {pid}).")
                continue
            journal = _own_journal(entry, own)  # again, under the lock: what is moved is what was checked
            if journal is not None:
                todo = [n for n in journal if _lstat(entry / n) is not None]
                try:
                    for n in todo:
                        os.replace(entry / n, directory / n)
                except OSError as exc:
                    warnings.append(f"could not finish the interrupted write in @{entry}@ ({exc.strerror}); "
                                    "remove it by hand once the cause is fixed.")
                    continue
                if todo:
                    warnings.append(
                        f"finished the write of an interrupted run (process {pid}): moved {', '.join(todo)} from @{entry}@ "
                        f"into {directory}, so its result there is whole again."
                    )
            else:
                warnings.append(f"removed @{entry}@, the unfinished work of an interrupted run (process {pid}).")
            shutil.rmtree(entry, ignore_errors=True)


def _remove_stale_lock(path: Path) -> None:
    """Remove a :func:`run_lock` file that no run holds (its run was killed); one held is left alone."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError:
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        if os.stat(path, follow_symlinks=False).st_ino == os.fstat(fd).st_ino:
            os.unlink(path)
    except OSError:  # held (BlockingIOError), gone, or no flock here
        pass
    finally:
        os.close(fd)


def pending_commits(directory: Path) -> list[tuple[Path, list[str]]]:
    """Staging directories in ``directory`` that hold a journal: commits a killed run did not finish, and their names.

    Only journals :func:`staged_names` accepts are listed (this only reads; :func:`recover` refuses the others).
    """
    out: list[tuple[Path, list[str]]] = []
    try:
        entries = list(Path(directory).iterdir())
    except OSError:
        return out
    for entry in entries:
        if _STAGING.fullmatch(entry.name):
            try:
                names = staged_names(entry)
            except (OutputError, OSError):
                continue
            if names is not None:
                out.append((entry, names))
    return out
