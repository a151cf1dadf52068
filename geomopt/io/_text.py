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
           "ints", "plain_ints", "gc_paused", "text_rows", "write_rows", "read_vertex_ids"]

_INT64_MAX = np.iinfo(np.int64).max


def write_rows(fh, prefix, A):
    """Rows of floats, each number in the shortest form that round-trips (``repr``)."""
    fh.writelines(prefix + " ".join(map(repr, row)) + "\n" for row in np.asarray(A, np.float64).tolist())



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
