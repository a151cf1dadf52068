"""The shared tokenizer (geomopt.io._text): NumPy parses whole sections, geomopt names the culprit.

NumPy's number parser must accept exactly the plain decimal syntax (FLOAT_RE / INT_RE), or the
readers would read what they promise to refuse; a refusal must name the token and its line
wherever it is in a large section; gathering tokens must keep them in order whichever way it
copies them.  Also: STL welding by hash stays exact when hashes collide.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from geomopt._runtime.errors import MeshFormatError
from geomopt.exact import weld as weld_module
from geomopt.io import _stl, _text
from geomopt.io._text import FLOAT_RE, INT_RE, Tokens, parse

ALPHABET = "0123456789+-.eEnaifty_xX( )"
token = st.text(alphabet=ALPHABET.replace(" ", ""), min_size=1, max_size=8).map(str.encode)
FAST = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def valid(tok, integer):
    if not (INT_RE if integer else FLOAT_RE).fullmatch(tok):
        return False
    return not integer or abs(int(tok)) < 2**63 - 1


@FAST
@given(tokens=st.lists(token, min_size=1, max_size=6), integer=st.booleans())
def test_numpy_parses_exactly_the_plain_decimal_syntax(tokens, integer):
    """Tokens NumPy would read beyond the syntax ('+1' as an integer, 'nan(x)', hex, '1_0') are refused."""
    dtype = np.int64 if integer else np.float64
    values = parse(b" ".join(tokens), dtype)
    ok = all(valid(t, integer) for t in tokens)
    assert (values is not None and len(values) == len(tokens)) == ok, tokens
    if ok:
        expected = [int(t) for t in tokens] if integer else [float(t) for t in tokens]
        np.testing.assert_array_equal(values, np.array(expected, dtype=dtype))


@pytest.mark.parametrize("text", [b"-", b"1 -", b"- 1", b"+1", b"1 +2"])
def test_signs_numpy_reads_alone_are_refused_in_integers(text):
    """NumPy reads a lone '-' as 0 and '- 1' as -1 (an OFF face '3 0 1 -' would name vertex 0)."""
    assert parse(text, np.int64) is None


def test_integers_beyond_int64_are_refused_not_clamped():
    assert parse(b"1 99999999999999999999", np.int64) is None
    assert parse(b"-99999999999999999999 1", np.int64) is None
    assert parse(b"9223372036854775806 -9223372036854775807", np.int64).tolist() == [2**63 - 2, -(2**63) + 1]


def test_floats_round_trip_every_bit():
    rng = np.random.default_rng(5)
    x = rng.normal(size=2000) * 10.0 ** rng.integers(-300, 300, 2000)
    x[:4] = [5e-324, -0.0, 1.7976931348623157e308, 2.2250738585072014e-308]
    assert np.array_equal(parse(" ".join(map(repr, x.tolist())).encode(), np.float64).view(np.int64), x.view(np.int64))


@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, 3000), data=st.data())
def test_a_bad_token_is_named_with_its_line_wherever_it_is(n, data):
    """The culprit of a large section is found by halving: its token and line, not a neighbour's."""
    at = data.draw(st.integers(0, n - 1))
    bad = data.draw(st.sampled_from([b"1_0", b"x", b"0x10", b"nan(1)", b"1.0.0", b"--1"]))
    lines = [b"%d.5 %d" % (i, i) for i in range(n)]
    lines[at] = b"%d.5 " % at + bad
    tokens = Tokens(b"header\n" + b"\n".join(lines) + b"\n", "f")
    with pytest.raises(MeshFormatError, match=rf"f, line {at + 2}: .*{re.escape(bad.decode())}"):
        tokens.numbers(1, len(tokens), np.float64)


@FAST
@given(words=st.lists(st.sampled_from([b"1", b"22", b"333", b"-4.5e1", b"x"]), min_size=1, max_size=40),
       spaces=st.lists(st.sampled_from([b" ", b"\n", b"\t", b"  \n "]), min_size=40, max_size=40), data=st.data())
def test_gather_keeps_the_chosen_tokens_in_order(words, spaces, data):
    """Either strategy (copy the kept tokens, or blank the others) gives the kept tokens in order."""
    text = b"".join(w + s for w, s in zip(words, spaces))
    keep = sorted(data.draw(st.sets(st.integers(0, len(words) - 1), min_size=1)))
    assert Tokens(text, "f").gather(np.array(keep)).split() == [words[i] for i in keep]


def test_the_whitespace_of_a_token_is_that_of_bytes_split():
    text = b" a\tb\x0bc\x0cd\re\nf  \x1cg"
    tokens = Tokens(text, "f")
    assert [tokens.text(t) for t in range(len(tokens))] == text.split()
    rows = tokens.rows()
    assert rows.lineno.tolist() == [1, 2] and rows.count.tolist() == [5, 2]


def test_stl_welding_is_exact_when_every_hash_collides(monkeypatch):
    rng = np.random.default_rng(2)
    V = rng.integers(0, 4, (30, 3)).astype(float)
    V[rng.random(V.shape) < 0.2] = -0.0
    corners = V[rng.integers(0, 30, 60)]
    want = _stl.weld(corners)
    monkeypatch.setattr(weld_module, "_mix", lambda z: np.zeros_like(z))
    got = _stl.weld(corners)
    assert np.array_equal(got[0].view(np.int64), want[0].view(np.int64)) and np.array_equal(got[1], want[1])
    ids = {}
    for c in corners + 0.0:
        ids.setdefault(c.tobytes(), len(ids))
    assert got[1].ravel().tolist() == [ids[c.tobytes()] for c in corners + 0.0]


def test_a_section_of_a_million_numbers_is_parsed_by_numpy_not_token_by_token(monkeypatch):
    """The fast path never builds a list of tokens: bytes.split is not called on the section."""
    text = b"\n".join(b"%d 1.5 2.5" % i for i in range(200000))
    tokens = Tokens(text, "f")
    calls = []
    monkeypatch.setattr(_text, "_valid", lambda *a: calls.append(a) or True)
    assert tokens.numbers(0, len(tokens), np.float64).shape == (600000,)
    assert not calls
