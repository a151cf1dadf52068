"""Text tokenizing shared by the text readers: byte-order marks, line ends, numbers parsed by NumPy.

Numbers are parsed by NumPy's C parser (``np.fromstring`` with a whitespace separator) over whole
spans of a file, never token by token; it refuses the same tokens as the plain decimal syntax
(``1``, ``-2.5``, ``1e-3``, ``nan``/``inf``) except four, checked before or after it: ``+`` on an
integer, a ``-`` alone in an integer (NumPy reads ``-`` as 0 and ``- 1`` as -1), ``nan(...)`` and
integers beyond int64 (which it clamps).  Only when a span does not parse is the culprit looked for
(by halving the span), to name it and its line.  Writers print floats in their shortest
round-trip form.
"""

from __future__ import annotations

import contextlib
import gc
import re
import warnings

import numpy as np

from .._runtime.errors import MeshFormatError
from .._runtime.validate import validate_indices
from ._files import read_input

__all__ = ["UTF8_BOM", "FLOAT_RE", "INT_RE", "show", "uncomment", "line_of", "text_data", "number_problem", "parse",
           "fits", "ints", "gc_paused", "ranges", "Tokens", "Rows", "ascii_rows", "write_rows", "write_int_rows",
           "read_vertex_ids"]

UTF8_BOM = b"\xef\xbb\xbf"
_OTHER_BOMS = ((b"\xff\xfe\x00\x00", "UTF-32"), (b"\x00\x00\xfe\xff", "UTF-32"),
               (b"\xff\xfe", "UTF-16"), (b"\xfe\xff", "UTF-16"))
#: A decimal number as C's strtod reads it (no '_', no hex, ASCII digits only), or nan/inf.
FLOAT_RE = re.compile(rb"[+-]?(?:(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|(?i:nan|inf|infinity))")
#: A decimal integer: ASCII digits with an optional minus sign (no '+', no '_').
INT_RE = re.compile(rb"-?[0-9]+")
_INT64 = np.iinfo(np.int64)
_LONE_MINUS = re.compile(rb"-(?![0-9])")


def write_rows(fh, prefix, A):
    """Rows of floats, each number in the shortest form that round-trips (``repr``)."""
    A = np.atleast_2d(np.asarray(A, np.float64)) if np.size(A) else np.zeros((0, 1))
    fh.write(((prefix + " ".join(["%r"] * A.shape[1]) + "\n") * len(A)) % tuple(A.ravel().tolist()))


def write_int_rows(fh, fmt, A):
    """Rows of integers, each row formatted by the %-format ``fmt`` (one ``%d`` per column, no newline)."""
    A = np.asarray(A, np.int64)
    fh.write(((fmt + "\n") * len(A)) % tuple(A.ravel().tolist()))


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
    data = data.removeprefix(UTF8_BOM)
    if b"\x00" in data:
        raise MeshFormatError(f"{what} {path} is a binary file (it contains NUL bytes); a text file is expected")
    for bad, why in ((UTF8_BOM, "a byte-order mark (U+FEFF) in the middle of the file; remove it (only one at "
                                "the very start is allowed)"),
                     (b"\r", "a carriage return (CR) not followed by a line feed; convert the file to LF or CRLF "
                             "line ends")):
        if bad == b"\r" and bad in data:
            data = data.replace(b"\r\n", b"\n")
        at = data.find(bad)
        if at >= 0:
            raise MeshFormatError(f"{path}, line {line_of(data, at)}: {why}")
    return data


def uncomment(data, marker=b"#"):
    """``data`` without the text from each ``marker`` to its line's end (line numbers kept)."""
    return re.sub(re.escape(marker) + rb"[^\n]*", b"", data) if marker in data else data


def line_of(data, at):
    """The line (1-based) of byte ``at`` of ``data``."""
    return data.count(b"\n", 0, at) + 1


def number_problem(token, kind, what=None):
    """Why ``token`` (bytes) is not a valid ``kind`` ('number' or 'integer'), in words; with
    ``what`` (the section), ``expected <kind> (<what>), found <token>``."""
    hint = ""
    if UTF8_BOM in token:
        hint = " (it contains a byte-order mark, U+FEFF)"
    elif b"_" in token:
        hint = " (underscores are not allowed in numbers)"
    elif kind == "integer" and FLOAT_RE.fullmatch(token):
        hint = " (an integer is required)"
    elif any(b > 127 for b in token):
        hint = " (it contains non-ASCII characters)"
    article = "an integer" if kind == "integer" else "a number"
    if what is not None:
        return f"expected {article} ({what}), found {show(token)}{hint}"
    example = "e.g. 0, 7 or 12" if kind == "integer" else "e.g. 1, -2.5 or 1e-3"
    return f"cannot read {show(token)} as {article}{hint}; expected a plain decimal {kind} ({example})"


def parse(span, dtype):
    """The whitespace-separated numbers of ``span`` (bytes) as ``dtype`` (float64 or int64), or
    ``None`` unless every token is a plain decimal of that kind (int64: within its range)."""
    integer = np.dtype(dtype).kind == "i"
    if not span:
        return np.zeros(0, dtype)
    if (b"+" in span or _LONE_MINUS.search(span)) if integer else b"(" in span:  # NumPy reads '- 1' as -1
        return None
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)  # "could not be read to its end": a bad token
        try:
            values = np.fromstring(span, dtype=dtype, sep=" ")
        except (ValueError, DeprecationWarning):
            return None
    if integer and values.size and (values.min() == _INT64.min or values.max() == _INT64.max):
        return None  # NumPy clamps what overflows; such values are read, if valid, token by token
    return values


def fits(values, code, where):
    """``values`` (numbers read as int64 or float64) if ``code`` (a NumPy type code) is real or every
    value fits that integer type; else a MeshFormatError at ``where``."""
    info = np.iinfo(code) if code[0] in "iu" else None
    if info is not None and values.size and (values.min() < info.min or values.max() > info.max):
        raise MeshFormatError(f"{where}: a value does not fit the declared type {np.dtype(code).name}")
    return values


def _valid(token, integer):
    if not (INT_RE if integer else FLOAT_RE).fullmatch(token):
        return False
    return not integer or _INT64.min < int(token) < _INT64.max


def ints(tokens, where):
    """``int64`` array of decimal integer tokens (a list of bytes without whitespace); refuses other
    syntax and int64 overflow; ``where(i)`` locates token ``i`` for a message."""
    joined = Tokens(b" ".join(tokens), None)
    return joined.numbers(0, len(joined), np.int64, where=where)


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


def ranges(starts, lengths):
    """``starts[i] + 0 .. lengths[i] - 1`` for every ``i``, concatenated (int64)."""
    starts, lengths = np.asarray(starts, dtype=np.int64), np.asarray(lengths, dtype=np.int64)
    return np.repeat(starts - (np.cumsum(lengths) - lengths), lengths) + np.arange(int(lengths.sum()))


class Tokens:
    """The whitespace-separated tokens of a text, located by NumPy in a few passes over its bytes.

    Token ``t`` is ``data[start[t]:end[t]]`` (whitespace as ``bytes.split`` sees it); no list
    of tokens is built.  ``newlines`` holds the positions of the line feeds (line numbers; ``data``
    starts on file line ``line``).
    """

    def __init__(self, data, path, line=1):
        self.data, self.path, self.line = data, path, line  # data's first line is file line ``line``
        raw = np.frombuffer(data, np.uint8)
        solid = (raw != 32) & ((raw - 9) > 4)  # not space, \t \n \v \f \r (uint8: raw < 9 wraps high)
        edges = np.flatnonzero(solid[1:] != solid[:-1]) + 1
        edges = np.concatenate([[0] * bool(solid[:1].any()), edges, [len(raw)] * bool(solid[-1:].any())])
        edges = edges.astype(np.int64)
        self.start, self.end = edges[0::2], edges[1::2]
        self.newlines = np.flatnonzero(raw == 10)

    def __len__(self):
        return len(self.start)

    def text(self, t):
        """Token ``t`` (bytes)."""
        return self.data[self.start[t]:self.end[t]]

    def lineno(self, t):
        """The line (1-based) of token ``t``."""
        return int(np.searchsorted(self.newlines, self.start[min(t, len(self) - 1)])) + self.line

    def numbers(self, t0, t1, dtype, what=None, where=None):
        """Tokens ``t0:t1`` as ``dtype`` (float64 or int64), or a MeshFormatError naming the first bad
        one, its line and ``what`` (``where(t)``, if given, locates token ``t`` instead of its line)."""
        if t1 <= t0:
            return np.zeros(0, dtype)
        values = parse(self.data[self.start[t0]:self.end[t1 - 1]], dtype)
        if values is not None and len(values) == t1 - t0:
            return values
        self.refuse(self.first_bad(np.arange(t0, t1), dtype), dtype, what, where)

    def numbers_at(self, index, dtype, what=None, where=None):
        """Tokens ``index`` (ascending int array) as ``dtype``; refuses as :meth:`numbers`."""
        values = parse(self.gather(index), dtype)
        if values is not None and len(values) == len(index):
            return values
        self.refuse(self.first_bad(np.asarray(index), dtype), dtype, what, where)

    def gather(self, index):
        """Bytes holding the tokens ``index`` (ascending int array) in order, whitespace between them:
        the kept tokens copied into spaces, or (when they are most of the bytes) the bytes they
        span with the other tokens blanked, whichever moves fewer bytes."""
        index = np.asarray(index, dtype=np.int64)
        if not index.size:
            return b""
        t0, t1 = int(index[0]), int(index[-1]) + 1
        base, stop = int(self.start[t0]), int(self.end[t1 - 1])
        if len(index) == t1 - t0:
            return self.data[base:stop]
        drop = np.ones(t1 - t0, dtype=bool)
        drop[index - t0] = False
        drop = np.flatnonzero(drop) + t0
        raw = np.frombuffer(self.data, np.uint8)
        length = self.end[drop] - self.start[drop]
        if 2 * int(length.sum()) < stop - base:
            span = raw[base:stop].copy()
            span[ranges(self.start[drop] - base, length)] = 32
            return span.tobytes()
        length = self.end[index] - self.start[index]
        at = np.cumsum(length + 1) - length - 1  # where each kept token goes, one space after each
        out = np.full(int(at[-1] + length[-1]), 32, dtype=np.uint8)
        out[ranges(at, length)] = raw[ranges(self.start[index], length)]
        return out.tobytes()

    def first_bad(self, index, dtype):
        """The first of the tokens ``index`` that is not a plain decimal ``dtype`` (they do not all
        parse): halved while a half fails to parse, then the last few checked one by one."""
        while len(index) > 16:
            half = index[:len(index) // 2]
            values = parse(self.gather(half), dtype)
            index = half if values is None or len(values) != len(half) else index[len(half):]
        integer = np.dtype(dtype).kind == "i"
        return next((t for t in index.tolist() if not _valid(self.text(t), integer)), int(index[0]))

    def refuse(self, t, dtype, what=None, where=None):
        """Refuse token ``t``, which is not a plain decimal ``dtype``."""
        token, integer = self.text(t), np.dtype(dtype).kind == "i"
        place = where(t) if where is not None else f"{self.path}, line {self.lineno(t)}"
        if integer and INT_RE.fullmatch(token):
            raise MeshFormatError(f"{place}: the integer {show(token)} is too large")
        raise MeshFormatError(f"{place}: {number_problem(token, 'integer' if integer else 'number', what)}")

    def rows(self):
        """The non-blank lines as :class:`Rows`."""
        first = np.searchsorted(self.start, np.r_[0, self.newlines + 1])
        count = np.diff(np.r_[first, len(self)])
        keep = np.flatnonzero(count)
        return Rows(self, first[keep], count[keep], keep + self.line)


class Rows:
    """The non-blank lines of a :class:`Tokens` text: row ``r`` is file line ``lineno[r]`` and holds
    the tokens ``first[r] : first[r] + count[r]``.  Used by the readers whose messages name the line."""

    def __init__(self, tokens, first, count, lineno):
        self.tokens, self.path = tokens, tokens.path
        self.first, self.count, self.lineno = first, count, lineno
        self.head = np.frombuffer(tokens.data, np.uint8)[tokens.start[first]] if len(first) else \
            np.zeros(0, np.uint8)

    def __len__(self):
        return len(self.count)

    def key(self, r):
        """Row ``r``'s first token (bytes)."""
        return self.tokens.text(self.first[r])

    def at(self, r):
        """Row ``r``'s text, for messages."""
        t = self.tokens
        return t.data[t.start[self.first[r]]:t.end[self.first[r] + self.count[r] - 1]].decode(errors="replace")[:60]

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

    def ints(self, a, b, what, column=None):
        """Integers of rows ``a:b`` (all their tokens, or token ``column`` of each), int64."""
        return self._numbers(a, b, np.int64, what, column)

    def floats(self, a, b, what):
        """Every token of rows ``a:b`` as float64 (plain decimal numbers, or nan/inf), flat."""
        return self._numbers(a, b, np.float64, what, None)

    def _numbers(self, a, b, dtype, what, column):
        if b <= a:
            return np.zeros(0, dtype)
        if column is not None:
            return self.tokens.numbers_at(self.first[a:b] + column, dtype, what)
        return self.tokens.numbers(self.first[a], self.first[b - 1] + self.count[b - 1], dtype, what)


def ascii_rows(data, path, what):
    """The :class:`Rows` of an ASCII file (``what``: the format, for messages); NUL and non-ASCII
    bytes are refused."""
    if b"\x00" in data:
        raise MeshFormatError(f"{what} file {path} contains NUL bytes: it is a binary file; only ASCII "
                              f"{what} files are supported (re-export it as ASCII)")
    if not data.isascii():
        at = next(i for i, b in enumerate(data) if b > 127)
        raise MeshFormatError(f"{path}, line {line_of(data, at)}: a non-ASCII byte; {what} files are ASCII text")
    return Tokens(data, path).rows()


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
        Ids out of range or repeated (:func:`~geomopt._runtime.validate.validate_indices`).
    """
    path, data = read_input(path, f"{what} file", empty_ok=True)
    tokens = Tokens(text_data(data, path, f"{what} file"), path)
    try:
        ids = tokens.numbers(0, len(tokens), np.int64)
    except MeshFormatError as exc:
        raise MeshFormatError(f"{exc}; a {what} file holds 0-based vertex ids, one per line") from None
    return validate_indices(ids, n_vertices, f"{path}: {what}")
