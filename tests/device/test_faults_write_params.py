"""``write-params`` refuses bad files before connecting, bad values before writes.

The rules are docs/design.md §4.

Validation order: schema, keys and finite numbers are checked before any bus is opened
(the session class is replaced by a tripwire); the device's ranges, which need its nominal
LSBs, after connecting but before the first SDO download (every download is recorded, and
the node's calibration objects compared before and after). Both exit 2. The range checks run
against both nodes (``make_device``) on a virtual bus.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from canimucal.cli.main import COMMANDS, main
from canimucal.device.bus import SdoChannel
from canimucal.runtime.wiring import Devices
from tests.support.nodes import DeviceUnderTest

pytestmark = pytest.mark.skipif(
    "write-params" not in COMMANDS, reason="the write-params verb is not registered yet"
)

GOOD: dict[str, Any] = {
    "schema": "canimucal.calibration/1",
    "device": {"node_id": 16, "serial": 0},
    "accel": {"bias": [1.0, 2.0, 3.0], "K": [[208.0, 0, 0], [0, 209, 0], [0, 0, -210]]},
}


class _Connected(BaseException):
    """Raised by the tripwire: the command tried to open a bus."""


def _with(path: tuple[str, ...], value: Any) -> dict[str, Any]:
    doc = json.loads(json.dumps(GOOD))
    target = doc
    for key in path[:-1]:
        target = target.setdefault(key, {})
    target[path[-1]] = value
    return doc


@pytest.fixture
def tripwire(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(self: Devices, *args: Any, **kwargs: Any) -> None:
        raise _Connected

    monkeypatch.setattr(Devices, "__init__", refuse)


@pytest.mark.parametrize(
    ("text", "says"),
    [
        (json.dumps(GOOD).replace("1.0", "NaN"), "NaN is not allowed"),
        (json.dumps(GOOD).replace("208.0", "Infinity"), "Infinity is not allowed"),
        (json.dumps(GOOD).replace("3.0", "-Infinity"), "Infinity is not allowed"),
        (json.dumps(_with(("colour",), "red")), "colour: unknown key"),
        (json.dumps(_with(("accel", "colour"), 1)), "colour"),
        (json.dumps(_with(("schema",), "canimucal.calibration/2")), "schema"),
        (json.dumps(_with(("accel", "K"), [[1, 2, 3], [2, 4, 6], [0, 0, 1]])), "singular"),
    ],
)
def test_bad_file_refused_before_connecting(
    tripwire: None, tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str, says: str
) -> None:
    path = tmp_path / "cal.json"
    path.write_text(text)
    code = main(["write-params", str(path), "--sim", "--force"])  # _Connected if it connects
    err = capsys.readouterr().err
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and says in lines[0], err


@pytest.fixture
def downloads(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[tuple[int, int]]]:
    """Record every SDO download the client makes."""
    seen: list[tuple[int, int]] = []
    download = SdoChannel.download

    def recording_download(self: SdoChannel, index: int, sub: int, data: bytes) -> None:
        seen.append((index, sub))
        download(self, index, sub, data)

    monkeypatch.setattr(SdoChannel, "download", recording_download)
    yield seen


@pytest.mark.parametrize(
    ("path", "value"),
    [
        (("accel", "K"), [[100.0, 0, 0], [0, 209, 0], [0, 0, -210]]),  # M diagonal +109 %
        (("accel", "K"), [[208.0, 80, 0], [0, 209, 0], [0, 0, -210]]),  # off-diagonal 0.38
        (("accel", "bias"), [70000.0, 0, 0]),  # |bias| > 65536 counts
        (("base_tilt_deg",), {"alpha0": 15.0, "beta0": 0.0}),  # 0.26 rad > 0.2
        (("gyro",), {"G": [[2000.0, 0, 0], [0, 0, 0], [0, 0, 0]]}),  # |G| > 1000
    ],
)
def test_out_of_range_refused_before_writing_anything(
    downloads: list[tuple[int, int]],
    make_device: Callable[..., DeviceUnderTest],
    bus_channel: str,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    path: tuple[str, ...],
    value: Any,
) -> None:
    device = make_device()
    factory = device.raw_objects()
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(_with(path, value)))
    bus = ["--interface", "virtual", "--channel", bus_channel]
    argv = ["write-params", str(cal), *bus, "--force", "--backup-dir", str(tmp_path / "b")]
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.startswith("error: ") and len(err.strip().splitlines()) == 1, err
    assert downloads == []  # nothing written, not even valid = 0
    assert device.raw_objects() == factory  # the node still holds its factory set
    assert not device.calibration_valid() and not (tmp_path / "b").exists()
