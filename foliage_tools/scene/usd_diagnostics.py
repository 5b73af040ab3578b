"""What USD says about an input, in the user's terms.

USD prints its warnings on stderr itself (with absolute paths and the C++
source line of the diagnostic) and words its errors for its own developers.
Here: its diagnostics are captured while a stage is opened or validated and
logged instead (``-vv`` shows them), absolute paths in its messages become
paths relative to the asset, its C++ namespaces are dropped, and a syntax
error USD finds only at the next token (a list that never closes) is placed
where the file needs fixing.
"""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from pxr import Tf, UsdUtils

log = logging.getLogger(__name__)


@contextmanager
def captured(covered: list[str] | None = None) -> Iterator[None]:
    """Take USD's warnings and status messages issued inside the block instead of letting USD print them.

    Each is logged on leaving the block: at debug level when it contains one of ``covered`` (texts the caller
    reports in its own words, which it may add to inside the block) or when ``covered`` is None (the caller
    reports all of them), and as a warning otherwise, so nothing USD says is lost.
    """
    delegate = UsdUtils.CoalescingDiagnosticDelegate()  # while one is registered, USD prints nothing itself
    try:
        yield
    finally:
        diagnostics = delegate.TakeUncoalescedDiagnostics()
        del delegate  # unregisters it: USD prints again outside the block
        for d in diagnostics:
            text = commentary(d)
            quiet = covered is None or any(c in text for c in covered) or "STATUS" in str(d.diagnosticCodeString)
            log.log(logging.DEBUG if quiet else logging.WARNING, "USD: %s", text)


def commentary(diagnostic) -> str:
    """What a USD diagnostic (an error of a ``Tf.ErrorException``, a captured warning) says, stripped; bytes that are
    not UTF-8 in it (quoted from a file that is not) as ``\\xNN`` instead of failing to decode."""
    try:
        return str(getattr(diagnostic, "commentary", "")).strip()
    except UnicodeDecodeError as exc:
        raw = exc.object if isinstance(exc.object, bytes) else b""
        return raw.decode("utf-8", errors="backslashreplace").strip() or "text that is not UTF-8"


def not_utf8(path: str | os.PathLike) -> str | None:
    """Where a text layer first holds bytes that are not UTF-8 (``line L, column C: byte 0xff is not UTF-8``), or
    None when it is UTF-8 (or binary: a crate file, a zip)."""
    try:
        with open(path, "rb") as f:
            data = f.read(64 << 20)
    except OSError:
        return None
    if not data.startswith(b"#usda"):
        return None
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        column = exc.start - (data.rfind(b"\n", 0, exc.start) + 1) + 1
        return f"line {line}, column {column}: byte 0x{data[exc.start]:02x} is not UTF-8"
    return None


#: an absolute path as USD quotes it in a message: @/x/y.usda@ or '/x/y.usda'
_QUOTED_ABSOLUTE = re.compile(r"(?P<q>[@'])(?P<path>/[^@'\n]*)(?P=q)")


def relative_paths(text: str, asset: str | os.PathLike) -> str:
    """``text`` with the absolute paths USD quotes in it (``@...@``, ``'...'``) made relative to ``asset``'s
    folder (``./x.usda``, ``../y.usda``), as the asset names them. A quoted path is taken for a file when its
    folder is on disk or its name has an extension (a missing reference's folder may be missing too; a prim
    name has no dot); others (a prim path in quotes, say) and one sharing no folder with the asset stay as they
    are."""
    folder = os.path.dirname(os.path.abspath(asset))

    def relative(m: re.Match) -> str:
        path = m["path"]
        is_file = os.path.isdir(os.path.dirname(path)) or "." in os.path.basename(path)
        if not is_file or os.path.commonpath([folder, path]) == os.path.sep:
            return m[0]
        rel = os.path.relpath(path, folder)
        return f"{m['q']}{rel if rel.startswith('..') else './' + rel}{m['q']}"

    return _QUOTED_ABSOLUTE.sub(relative, text)


#: USD's versioned C++ namespaces and its text parser's, in the rule names its parse errors quote
_CXX_NAMESPACE = re.compile(r"pxrInternal_v\w*?__pxrReserved__\w*::|Sdf_TextFileFormatParser::")


def without_cxx_names(text: str) -> str:
    return _CXX_NAMESPACE.sub("", text)


def open_failure(exc: Tf.ErrorException, path: str | os.PathLike) -> str:
    """Why USD could not open ``path``, from the errors of ``exc``: what it says about the file (its first
    errors; the last, "Failed to open layer", only repeats that it failed), without the C++ function, source file
    and line of each diagnostic, and naming the file "the file"."""
    said = [commentary(e) for e in exc.args]
    said = [s for s in said if s] or [str(exc).strip() or "unknown error"]
    causes = [s for s in said if not s.startswith("Failed to open layer")] or said
    plain = without_cxx_names("; ".join(causes))
    names = {str(path), os.path.abspath(path), str(Path(path).resolve())}
    for name in sorted(names, key=len, reverse=True):
        plain = re.sub(r"[<@']?" + re.escape(name) + r"[>@']?", "the file", plain)
    return plain.rstrip(".")


#: the closing bracket of USD's list and tuple values (its text parser's rules ListValueClose, TupleValueClose)
_CLOSERS = {"ListValueClose": "]", "TupleValueClose": ")"}
_EXPECTED_CLOSER = re.compile(r"parse error matching (?P<rule>\w+) at '(?P<at>.*)'(?: in (?P<where><[^>]*>))?$", re.S)


def _code_end(line: str) -> int:
    """The length of ``line`` without a trailing ``#`` or ``//`` comment and whitespace (quotes respected)."""
    quote = ""
    for k, c in enumerate(line):
        if quote:
            quote = "" if c == quote else quote
        elif c in "\"'":
            quote = c
        elif c == "#" or line.startswith("//", k):
            line = line[:k]
            break
    return len(line.rstrip())


def place_unclosed(file: str, line: int, column: int, what: str) -> tuple[int, int, str]:
    """Where a list or tuple value that never closes needs its bracket, and what to say about it.

    USD's parser reports a missing ``]`` (or ``)``) at the next token, which is often on a later line: the
    place to fix is right after the last value, at the end of the text before that token (comments and blank
    lines skipped). Other syntax errors, and a file that cannot be read back, are returned unchanged.
    """
    found = _EXPECTED_CLOSER.match(without_cxx_names(what))
    if found is None or found["rule"] not in _CLOSERS:
        return line, column, what
    try:
        lines = Path(file).read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError:
        return line, column, what
    if not 0 < line <= len(lines):
        return line, column, what
    k, end = line, _code_end(lines[line - 1][: column - 1])  # the text before the token on its own line
    while end == 0 and k > 1:  # else the last line above with any
        k -= 1
        end = _code_end(lines[k - 1])
    if end == 0:
        return line, column, what
    closer = _CLOSERS[found["rule"]]
    of = f" of {found['where']}" if found["where"] else ""
    next_at = f"line {line}, column {column}" if line != k else f"column {column}"
    return k, end + 1, (f"the {'list' if closer == ']' else 'tuple'} value{of} has no closing '{closer}' here (or a ',' "
                        f"is missing before the next value): USD's parser met {found['at']!r} next, at {next_at}")
