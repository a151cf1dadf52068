"""Text tokenizing shared by the text readers: byte-order marks, line ends, number syntax.

Numbers must be plain decimal ASCII (``1``, ``-2.5``, ``1e-3``, ``nan``/``inf``); Python-only
spellings such as ``1_0``, ``+1`` (for integers), ``0x10`` or non-ASCII digits are refused
with a message naming the token.  Writers print floats in their shortest round-trip form.
"""

from __future__ import annotations

import contextlib
import gc
import re

import numpy as np

from .._errors import MeshFormatError
from .._validate import validate_indices
from ._files import existing_file, read_bytes

__all__ = ["UTF8_BOM", "FLOAT_RE", "INT_RE", "show", "text_data", "number_problem", "first_bad", "floats",
           "ints", "plain_ints", "gc_paused", "text_rows", "write_rows", "write_int_rows", "read_vertex_ids", "TokenRows"]

_INT64_MAX = np.iinfo(np.int64).max


def write_rows(fh, prefix, A):
    """Rows of floats, each number in the shortest form that round-trips (``repr``)."""
    A = np.atleast_2d(np.asarray(A, np.float64)) if np.size(A) else np.zeros((0, 1))
    fh.write(((prefix + " ".join(["%r"] * A.shape[1]) + "\n") * len(A)) % tuple(A.ravel().tolist()))


def write_int_rows(fh, fmt, A):
    """Rows of integers, each row formatted by the %-format ``fmt`` (one ``%d`` per column, no newline)."""
    A = np.asarray(A, np.int64)
    fh.write(((fmt + "\n") * len(A)) % tuple(A.ravel().tolist()))



# ------------------------------------------------------------------ text parsing

UTF8_BOM = b"\xef\xbb\xbf"
_OTHER_BOMS = ((b"\xff\xfe\x00\x00", "UTF-32"), (b"\x00\x00\xfe\xff", "UTF-32"),
               (b"\xff\xfe", "UTF-16"), (b"\xfe\xff", "UTF-16"))
#: A decimal number as C's strtod reads it (no '_', no hex, ASCII digits only), or nan/inf.
FLOAT_RE = re.compile(rb"[+-]?(?:(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|(?i:nan|inf|infinity))")
#: A decimal integer: ASCII digits with an optional minus sign (no '+', no '_').
INT_RE = re.compile(rb"-?[0-9]+")


def show(token):
    """A token (bytes) as printable text for a message."""
    text = token.decode("utf-8", errors="backslashreplace")
    return repr(text if len(text) <= 40 else text[:37] + "...")


def text_data(data, path, what):
    """``data`` with a leading UTF-8 byte-order mark removed; refuse what is not LF/CRLF ASCII-ish text.

    Refuses UTF-16/32 text (by its byte-order mark), NUL bytes (a binary file), a
    byte-order mark anywhere but at the start, and carriage returns not followed by a
    line feed.  CRLF line ends become LF.  Returns bytes.
    """
    for bom, name in _OTHER_BOMS:
        if data.startswith(bom):
            raise MeshFormatError(f"{what} {path} is {name} text (it starts with a {name} byte-order mark); "
                                  f"save it as UTF-8 or ASCII")
    if data.startswith(UTF8_BOM):
        data = data[len(UTF8_BOM):]
    if b"\x00" in data:
        raise MeshFormatError(f"{what} {path} is a binary file (it contains NUL bytes); a text file is expected")
    at = data.find(UTF8_BOM)
    if at >= 0:
        lineno = data.count(b"\n", 0, at) + 1
        raise MeshFormatError(f"{path}, line {lineno}: a byte-order mark (U+FEFF) in the middle of the "
                              f"file; remove it (only one at the very start is allowed)")
    if b"\r" in data:
        data = data.replace(b"\r\n", b"\n")
        at = data.find(b"\r")
        if at >= 0:
            lineno = data.count(b"\n", 0, at) + 1
            raise MeshFormatError(f"{path}, line {lineno}: a carriage return (CR) not followed by a line "
                                  f"feed; convert the file to LF or CRLF line ends")
    return data


def number_problem(token, kind):
    """Why ``token`` (bytes) is not a valid ``kind`` ('number' or 'integer'), in words."""
    hint = ""
    if UTF8_BOM in token:
        hint = " (it contains a byte-order mark, U+FEFF)"
    elif b"_" in token:
        hint = " (underscores are not allowed in numbers)"
    elif kind == "integer" and FLOAT_RE.fullmatch(token):
        hint = " (an integer is required)"
    elif any(b > 127 for b in token):
        hint = " (it contains non-ASCII characters)"
    example = "e.g. 0, 7 or 12" if kind == "integer" else "e.g. 1, -2.5 or 1e-3"
    return f"cannot read {show(token)} as {'an integer' if kind == 'integer' else 'a number'}{hint}; " \
           f"expected a plain decimal {kind} ({example})"


def first_bad(tokens, regex):
    """Index of the first token not fully matching ``regex``, or ``None``."""
    if all(map(regex.fullmatch, tokens)):
        return None
    return next(i for i, t in enumerate(tokens) if not regex.fullmatch(t))


def floats(tokens, where):
    """``float64`` array of decimal tokens (bytes); ``where(i)`` locates token ``i`` for a message.

    Python's ``float`` (which numpy applies to bytes) reads exactly the syntax of ``FLOAT_RE``
    plus underscores between digits, so tokens without ``_`` that it accepts are valid; the
    token-by-token check runs only to name a bad token.
    """
    if not tokens:
        return np.zeros(0)
    if b"_" not in b"".join(tokens):
        with contextlib.suppress(ValueError):
            return np.array(tokens, dtype=np.float64)
    bad = first_bad(tokens, FLOAT_RE)
    raise MeshFormatError(f"{where(bad)}: {number_problem(tokens[bad], 'number')}")


def ints(tokens, where):
    """``int64`` array of decimal integer tokens (bytes); refuses other syntax and values beyond int64.

    As in :func:`floats`: Python's ``int`` reads ``INT_RE`` plus ``+`` signs and underscores,
    so those two are excluded first and the token-by-token check names a bad token.
    """
    if not tokens:
        return np.zeros(0, dtype=np.int64)
    values = plain_ints(tokens, b"".join(tokens))
    if values is not None:
        return values
    bad = first_bad(tokens, INT_RE)
    if bad is not None:
        raise MeshFormatError(f"{where(bad)}: {number_problem(tokens[bad], 'integer')}")
    bad = next(i for i, t in enumerate(tokens) if abs(int(t)) > _INT64_MAX)
    raise MeshFormatError(f"{where(bad)}: the integer {show(tokens[bad])} is too large")


def plain_ints(tokens, joined):
    """``int64`` array of ``tokens`` if all are plain decimal integers within int64, else ``None``.

    ``joined`` is the tokens concatenated (with or without separators); Python's ``int`` reads
    exactly ``INT_RE`` once ``+`` and ``_`` are ruled out.
    """
    if b"_" in joined or b"+" in joined:
        return None
    try:
        return np.array(tokens, dtype=np.int64)
    except (ValueError, OverflowError):
        return None


@contextlib.contextmanager
def gc_paused():
    """Pause the cyclic garbage collector while a parser builds many small lists of tokens.

    Those containers trigger collections that traverse every tracked object in the process
    (JAX's included): measured 3x slower parsing of an 11k-vertex OFF file without this.
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def text_rows(lines, comment=b"#"):
    """Non-blank lines as ``(line number, tokens)``; text from ``comment`` to the line end is dropped."""
    if comment is not None:
        lines = [line.split(comment, 1)[0] if comment in line else line for line in lines]
    return [(lineno, tokens) for lineno, tokens in enumerate(map(bytes.split, lines), 1) if tokens]



def read_vertex_ids(path, n_vertices, what="handles"):
    """Read 0-based vertex ids (e.g. fixed vertices) from a text file.

    The ids are plain decimal integers separated by any whitespace (one per line is usual);
    an empty file means no vertex.  Text conventions as in :func:`text_data`.

    Parameters
    ----------
    path : str or os.PathLike
        The text file.
    n_vertices : int
        Number of mesh vertices ``n``; valid ids are ``0 .. n-1``.
    what : str
        What the ids are, for messages (``"handles"``: ``"<path>: handles has ..."``).

    Returns
    -------
    numpy.ndarray, shape (k,), int64
        The ids in file order.

    Raises
    ------
    MeshFormatError
        Missing or unreadable file, or a token that is not a plain decimal integer (with its line).
    MeshError
        Ids out of range or repeated (:func:`~geomopt._validate.validate_indices`).
    """
    path = existing_file(path, f"{what} file")
    data = text_data(read_bytes(path, f"{what} file"), path, f"{what} file")
    rows = text_rows(data.split(b"\n"), comment=None)
    tokens = [t for _, ts in rows for t in ts]
    owner = [lineno for lineno, ts in rows for _ in ts]

    def where(i):
        return f"{path}, line {owner[i]}"

    bad = first_bad(tokens, INT_RE)
    if bad is not None:
        raise MeshFormatError(f"{where(bad)}: {number_problem(tokens[bad], 'integer')}; a {what} file holds "
                              f"0-based vertex ids, one per line")
    return validate_indices(ints(tokens, where), n_vertices, f"{path}: {what}")


class TokenRows:
    """The non-blank lines of an ASCII mesh file, split into tokens in a few passes (no list per line).

    Row ``r`` (a non-blank line) is file line ``lineno[r]`` and holds the tokens
    ``tokens[start[r]:start[r] + count[r]]`` (bytes); ``first[r]`` is its first token.  Used by
    the Gmsh and Medit readers, whose messages name the line at fault.
    """

    def __init__(self, data, path, what):
        if b"\x00" in data:
            raise MeshFormatError(f"{what} file {path} contains NUL bytes: it is a binary file; only ASCII "
                                  f"{what} files are supported (re-export it as ASCII)")
        if not data.isascii():
            at = next(i for i, b in enumerate(data) if b > 127)
            line = data.count(b"\n", 0, at) + 1
            raise MeshFormatError(f"{path}, line {line}: a non-ASCII byte; {what} files are ASCII text")
        raw = np.frombuffer(data, np.uint8)
        space = np.isin(raw, np.frombuffer(b" \t\n\r\x0b\x0c", np.uint8))  # what bytes.split() splits on
        begins = ~space
        begins[1:] &= space[:-1]
        line = np.cumsum(raw == 10) - (raw == 10)
        per_line = np.bincount(line[begins], minlength=int(line[-1]) + 1)
        self.path = path
        self.lineno = np.flatnonzero(per_line) + 1
        self.count = per_line[per_line > 0]
        self.start = np.concatenate([[0], np.cumsum(self.count)[:-1]]).astype(np.int64)
        self.tokens = data.split()
        self.first = [self.tokens[s] for s in self.start.tolist()]

    def __len__(self):
        return len(self.count)

    def at(self, r):
        """Line ``r``'s tokens as text, for messages."""
        return b" ".join(self.tokens[self.start[r]:self.start[r] + self.count[r]]).decode()[:60]

    def counted(self, a, held, count, section):
        """Section ``section`` opened on row ``a`` declares ``count`` entries and holds ``held``."""
        if held != count:
            fix = "fix the count" if held > count else "the file is truncated or the count is wrong"
            raise MeshFormatError(f"{self.path}: section {section} (line {self.lineno[a]}) declares {count} "
                                  f"entries but holds {held}; {fix}")

    def width(self, a, b, width, what):
        """Rows ``a:b`` must hold ``width`` tokens each."""
        bad = np.flatnonzero(self.count[a:b] != width)
        if bad.size:
            r = a + int(bad[0])
            raise MeshFormatError(f"{self.path}, line {self.lineno[r]}: the {what} entry has {self.count[r]} "
                                  f"values, expected {width}")

    def _slice(self, a, b, column):
        if column is None:
            return self.tokens[self.start[a]:self.start[b - 1] + self.count[b - 1]]
        return [self.tokens[s + column] for s in self.start[a:b].tolist()]

    def _culprit(self, a, b, column, regex, what, kind):
        for r in range(a, b):
            row = self.tokens[self.start[r]:self.start[r] + self.count[r]]
            for t in (row if column is None else row[column:column + 1]):
                if not regex.fullmatch(t) or (kind == "an integer" and abs(int(t)) > _INT64_MAX):
                    raise MeshFormatError(f"{self.path}, line {self.lineno[r]}: expected {kind} ({what}), "
                                          f"found {t.decode()[:40]!r}")
        raise AssertionError("unreachable")

    def ints(self, a, b, what, column=None):
        """Integers of rows ``a:b`` (all their tokens, or token ``column`` of each), int64."""
        if b <= a:
            return np.zeros(0, dtype=np.int64)
        toks = self._slice(a, b, column)
        values = plain_ints(toks, b"".join(toks))
        if values is not None:
            return values
        self._culprit(a, b, column, INT_RE, what, "an integer")

    def floats(self, a, b, what):
        """Every token of rows ``a:b`` as float64 (plain decimal numbers, or nan/inf), flat."""
        if b <= a:
            return np.zeros(0)
        toks = self._slice(a, b, None)
        if b"_" not in b"".join(toks):
            with contextlib.suppress(ValueError):
                return np.array(toks, dtype=np.float64)  # Python's float: FLOAT_RE's syntax, plus '_'
        self._culprit(a, b, None, FLOAT_RE, what, "a number")
