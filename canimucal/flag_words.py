"""How the command-line shells (``cli``, ``tui``) word an error's options as flags.

Library errors speak the Python API (``pass overwrite=True``, ``prior_k_sigma must be > 0``)
and list those spellings in :attr:`~canimucal.errors.CanimucalError.options`; the shells,
whose users typed flags, show the flag instead (``--overwrite``, ``--prior-k-sigma``). Only
the shells import this module (docs/design.md §1, §7).
"""

from __future__ import annotations

import re

from canimucal.errors import CanimucalError

FLAGS: dict[str, str] = {
    "overwrite=True": "--overwrite",
    "force=True": "--force",
    "store=False": "--no-store",
    "store_sub=3": "--store-sub 3",
    "store_sub": "--store-sub",
    "format=": "--format",
    "give plan": "give --plan",
    "sample_rate_hz": "--sample-rate-hz",
    "tolerance_deg": "--tolerance-deg",
    "latitude_deg": "--latitude-deg",
    "gyro='nav'": "--gyro nav",
    "gyro='moves'": "--gyro moves",
    "prior_k_sigma": "--prior-k-sigma",
    "prior_k": "--prior-k",
    "node_ids": "--node-id",
    "time_scale": "--time-scale",
    "give channel (and interface)": "give --channel (and --interface)",
    "use another interface": "use another --interface",
}
"""API spelling → the flag the command line uses for it."""


def worded_for_flags(error: BaseException) -> str:
    """Return ``str(error)`` with each of its :attr:`options` replaced by its flag.

    A spelling is replaced only where it stands as a word of its own (``prior_k`` inside
    ``prior_k_sigma`` is left alone); an option without a flag here stays as the API says it.
    """
    message = str(error)
    options = error.options if isinstance(error, CanimucalError) else ()
    for option in sorted(options, key=len, reverse=True):
        flag = FLAGS.get(option)
        if flag is None:
            continue
        tail = r"(?![\w])" if option[-1].isalnum() or option[-1] == "_" else ""
        message = re.sub(rf"(?<![\w-]){re.escape(option)}{tail}", flag, message)
    return message
