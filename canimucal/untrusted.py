"""Text that came from a device (its name, versions) made safe for each place it is shown.

A device string is untrusted: it may carry terminal escapes (ESC/CSI/OSC: clear the
screen, set the title, forge lines), bidirectional overrides, Markdown or HTML (forged
headings in a certificate) or Textual markup (``[/]`` crashes a widget). :func:`printable`
is applied where the text is read (``ImuClient.identity``), so every later use sees only
printable characters; :func:`markdown_text` adds the escaping a Markdown/HTML document
needs, :func:`markup_text` that of Textual's content markup.
"""

from __future__ import annotations

import re
import unicodedata

DEVICE_TEXT_MAX_BYTES = 256
"""Longest device string uploaded; a longer one is cut there and its transfer aborted."""

_MARKDOWN_SPECIAL = re.compile(r"([\\`*_{}\[\]()#+\-.!|<>&~=:\"'])")


def _escape_char(ch: str) -> str:
    code = ord(ch)
    if code <= 0xFF:
        return f"\\x{code:02x}"
    if code <= 0xFFFF:
        return f"\\u{code:04x}"
    return f"\\U{code:08x}"


def printable(text: str) -> str:
    r"""Escape everything that is not a printable character, as ``\xNN``/``\uNNNN``.

    C0 and C1 controls (ESC, CSI, OSC, BEL, CR, LF, TAB…), DEL, format characters (bidi
    overrides, zero-width joiners), surrogates, private-use and unassigned code points are
    escaped. Plain spaces stay; other separators (line/paragraph separators, odd spaces) are
    escaped too. Idempotent: what it returns passes through it unchanged, so text made
    printable when read can be escaped again for Markdown or markup without doubling.
    """
    out = []
    for ch in text:
        if ch == " " or (ch.isprintable() and unicodedata.category(ch)[0] not in "CZ"):
            out.append(ch)
        else:
            out.append(_escape_char(ch))
    return "".join(out)


def device_text(raw: bytes, truncated: bool = False) -> str:
    """Decode an uploaded device string (UTF-8, else Latin-1) and make it printable.

    Trailing NUL padding is dropped; ``truncated`` (the upload was cut at
    :data:`DEVICE_TEXT_MAX_BYTES`) appends ``…``.
    """
    raw = raw.rstrip(b"\0")
    try:
        decoded = raw.decode("utf-8")
    except UnicodeDecodeError:
        decoded = raw.decode("latin-1")
    text = printable(decoded)
    return text + "…" if truncated else text


def markdown_text(text: str) -> str:
    """Escape ``text`` for Markdown and the HTML it may be rendered to (after :func:`printable`).

    Every Markdown punctuation character gets a backslash and ``<``, ``>``, ``&`` become
    entities, so the text can neither open a heading, list, link or emphasis nor an HTML tag.
    """
    escaped = _MARKDOWN_SPECIAL.sub(r"\\\1", printable(text))
    return escaped.replace("\\<", "&lt;").replace("\\>", "&gt;").replace("\\&", "&amp;")


def markup_text(text: str) -> str:
    """Escape ``text`` for Textual content markup (after :func:`printable`)."""
    return printable(text).replace("[", "\\[")
