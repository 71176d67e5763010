"""Shared hypothesis strategies of the fuzz tests: byte-level edits with nasty tokens.

Used by ``tests/io/test_fuzz.py`` (the readers) and ``tests/cli/test_fuzz_files.py``
(the commands). Tokens are what breaks parsers of CSV, JSON and TOML: non-finite and huge
numbers, separators, line ends, invalid UTF-8, brackets, a future schema line.
"""

from __future__ import annotations

from hypothesis import strategies as st

TOKENS = [
    b"nan",
    b"NaN",
    b"inf",
    b"-Infinity",
    b"Infinity",
    b"1e999",
    b"-1",
    b"0",
    b"1.5",
    b"99999999999",
    b",",
    b",,",
    b"\n",
    b"\r\n",
    b"\n\n",
    b"#",
    b"# schema: canimucal.recording/2\n",
    b"# x: 1\n",
    b":",
    b" ",
    b"\t",
    b"\x00",
    b"\xff",
    b"\xc3",
    b"\xe2\x82\xac",
    b'"',
    b"{",
    b"}",
    b"[",
    b"]",
    b"null",
    b"true",
    b"[[positions]]\n",
    b"=",
    b"'",
    b'"schema"',
    b"e",
    b"-",
    b".",
    b"\\",
]


@st.composite
def byte_mutations(draw: st.DrawFn, base: bytes) -> bytes:
    """1–4 edits of ``base``: insert, delete, truncate, overwrite, duplicate or drop a line."""
    data = bytearray(base)
    for _ in range(draw(st.integers(1, 4))):
        at = draw(st.integers(0, len(data)))
        kind = draw(st.sampled_from(["insert", "delete", "truncate", "overwrite", "dup", "drop"]))
        token = draw(st.one_of(st.sampled_from(TOKENS), st.binary(min_size=1, max_size=6)))
        if kind == "insert":
            data[at:at] = token
        elif kind == "delete":
            del data[at : at + draw(st.integers(1, 20))]
        elif kind == "truncate":
            del data[at:]
        elif kind == "overwrite":
            data[at : at + len(token)] = token
        else:
            lines = bytes(data).split(b"\n")
            i = draw(st.integers(0, max(len(lines) - 1, 0)))
            if kind == "dup":
                lines.insert(i, lines[i])
            else:
                del lines[i]
            data = bytearray(b"\n".join(lines))
    return bytes(data)
