"""Modal screens: yes/no confirmations, the error modal, the mount and the site question."""

from __future__ import annotations

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.screen import ModalScreen
from textual.widgets import Button, Input, Static

from canimucal.errors import InputError
from canimucal.io.mounting import BODY
from canimucal.io.site_memory import LastSite
from canimucal.model.mounting import MountingMap
from canimucal.tui.widgets import PlainStatic


class Confirm(ModalScreen[bool]):
    """Ask a yes/no question: True for yes (``y``), False for no (``n``, escape).

    The safe answer, no, has the focus; subclasses name the question and the two buttons.
    """

    QUESTION = "Are you sure?"
    YES = "Yes"
    NO = "No"
    BINDINGS = [
        Binding("y", "answer(True)", "Yes"),
        Binding("n,escape", "answer(False)", "No"),
    ]

    def __init__(self, text: str) -> None:
        super().__init__()
        self.text = text

    def compose(self) -> ComposeResult:
        """Question, explanation and two buttons."""
        with Vertical(id="dialog"):
            yield Static(self.QUESTION, classes="dialog-title")
            yield PlainStatic(self.text, id="confirm-text")
            with Horizontal(classes="buttons"):
                yield Button(f"{self.YES} (y)", variant="warning", id="yes")
                yield Button(f"{self.NO} (n)", variant="primary", id="no")

    def on_mount(self) -> None:
        """Focus the safe choice."""
        self.query_one("#no", Button).focus()

    def on_button_pressed(self, event: Button.Pressed) -> None:
        """Answer from a button."""
        self.dismiss(event.button.id == "yes")

    def action_answer(self, yes: bool) -> None:
        """Answer from a key."""
        self.dismiss(yes)


class ConfirmWrite(Confirm):
    """Ask before writing: True to write, False to go back to the results."""

    QUESTION = "Write the calibration?"
    YES = "Write"
    NO = "Cancel"


class ConfirmQuit(Confirm):
    """Ask before quitting a session in progress; the text says what is kept."""

    QUESTION = "Quit the session in progress?"
    YES = "Quit"
    NO = "Stay"


class ConfirmSkip(Confirm):
    """Ask before leaving a position out of the fit."""

    QUESTION = "Skip this position?"
    YES = "Skip"
    NO = "Stay"


class ErrorModal(ModalScreen[None]):
    """An error: its short title and one-line message (never a traceback)."""

    BINDINGS = [Binding("enter,escape", "close", "Close")]

    def __init__(self, title: str, message: str) -> None:
        super().__init__()
        self.error_title = title
        self.message = message

    def compose(self) -> ComposeResult:
        """Title, message and an OK button."""
        with Vertical(id="dialog", classes="error"):
            yield Static(self.error_title, classes="dialog-title", id="error-title")
            yield PlainStatic(self.message, id="error-message")
            with Horizontal(classes="buttons"):
                yield Button("OK (enter)", variant="error", id="ok")

    def on_mount(self) -> None:
        """Focus the button."""
        self.query_one("#ok", Button).focus()

    def on_button_pressed(self, event: Button.Pressed) -> None:
        """Close."""
        self.dismiss(None)

    def action_close(self) -> None:
        """Close."""
        self.dismiss(None)


class MountModal(ModalScreen[MountingMap | str | None]):
    """Ask how the unit sits in the vehicle: a map, ``body``, or None (escape: unchanged).

    The map is checked as it is entered (a mirror image or a word used twice is refused
    here, with the reason); the caller saves it for the unit's serial.
    """

    BINDINGS = [Binding("escape", "cancel", "Cancel")]

    def __init__(self, current: str, serial: int | None) -> None:
        super().__init__()
        self.current = current
        self.serial = serial

    def compose(self) -> ComposeResult:
        """Question, explanation, the map as text and the reason it is refused."""
        unit = f"serial {self.serial}" if self.serial is not None else "this unit"
        with Vertical(id="dialog"):
            yield Static("How is the unit mounted?", classes="dialog-title")
            yield PlainStatic(
                "The vehicle direction of each unit axis (forward, back, left, right, up, "
                f"down), e.g. x=forward,y=down,z=left; saved for {unit}. 'body' words the "
                "instructions in the unit's own axes. Enter to use, escape to keep."
            )
            yield Input(self.current, id="mount-input")
            yield PlainStatic("", id="mount-error")

    def on_input_submitted(self, event: Input.Submitted) -> None:
        """Use the map entered, or say why it cannot be used."""
        text = event.value.strip()
        if text.lower() == BODY:
            self.dismiss(BODY)
            return
        try:
            self.dismiss(MountingMap.parse(text))
        except InputError as exc:
            self.query_one("#mount-error", PlainStatic).update(str(exc))

    def action_cancel(self) -> None:
        """Keep the map as it was."""
        self.dismiss(None)


G_RANGE_MS2 = (9.7, 9.9)
"""The local gravity the site question takes (anywhere people calibrate on Earth)."""


def site_answer(values: dict[str, str], *, needs_latitude: bool) -> LastSite:
    """Return the site question's answer from its fields, or InputError saying what is wrong.

    ``values``: operator, site, latitude (°), height (m, empty: 0), g (m/s², empty: normal
    gravity at latitude and height). The operator and latitude or g are needed; the
    navigation gyro needs the latitude (the Earth rate depends on it).
    """

    def number(key: str, what: str) -> float | None:
        text = values.get(key, "").strip()
        if not text:
            return None
        try:
            value = float(text)
        except ValueError:
            raise InputError(f"{what} must be a number, got {text!r}") from None
        if value != value or value in (float("inf"), float("-inf")):
            raise InputError(f"{what} must be a finite number, got {text!r}")
        return value

    operator = values.get("operator", "").strip()
    latitude = number("latitude", "latitude")
    height = number("height", "height")
    g = number("g", "g")
    if not operator:
        raise InputError("the operator's name is needed (it goes on the certificate)")
    if latitude is not None and not -90.0 <= latitude <= 90.0:
        raise InputError(f"latitude must be within [-90, 90] °, got {latitude:g}")
    if g is not None and not G_RANGE_MS2[0] <= g <= G_RANGE_MS2[1]:
        raise InputError(f"g must be within [{G_RANGE_MS2[0]}, {G_RANGE_MS2[1]}] m/s², got {g:g}")
    if latitude is None and g is None:
        raise InputError("give the latitude (and height), or the local g")
    if needs_latitude and latitude is None:
        raise InputError("the navigation gyro needs the latitude (the Earth rate depends on it)")
    return LastSite(operator, values.get("site", "").strip(), latitude, height, g)


class SiteModal(ModalScreen[LastSite | None]):
    """Ask who calibrates where, before the first position; None (escape): back to the plan.

    Operator, site, latitude and height, or g, each offered as last used. g is never
    assumed: without latitude or g the answer is refused, with the reason.
    """

    BINDINGS = [Binding("escape", "cancel", "Back")]
    FIELDS = (
        ("operator", "operator"),
        ("site", "site name"),
        ("latitude", "latitude, ° (north +)"),
        ("height", "height, m (empty: 0)"),
        ("g", "g, m/s² (empty: latitude)"),
    )

    def __init__(self, last: LastSite, *, needs_latitude: bool = False) -> None:
        super().__init__()
        self.last = last
        self.needs_latitude = needs_latitude

    def _offered(self, key: str) -> str:
        last = self.last
        value = {
            "operator": last.operator,
            "site": last.site_name,
            "latitude": last.latitude_deg,
            "height": last.height_m,
            "g": last.g,
        }[key]
        return "" if value is None else value if isinstance(value, str) else f"{value:.10g}"

    def compose(self) -> ComposeResult:
        """Question, one field per value (last used offered) and the reason it is refused."""
        with Vertical(id="dialog", classes="site"):
            yield Static("Who calibrates, and where?", classes="dialog-title")
            yield PlainStatic(
                "Latitude and height, or g, set the gravity the fit uses. Enter to start, "
                "escape to go back."
            )
            for key, label in self.FIELDS:
                with Horizontal(classes="site-row"):
                    yield PlainStatic(label, classes="site-label")
                    yield Input(self._offered(key), id=f"site-{key}")
            yield PlainStatic("", id="site-error")

    def values(self) -> dict[str, str]:
        """Return the fields as entered."""
        return {key: self.query_one(f"#site-{key}", Input).value for key, _ in self.FIELDS}

    def on_input_submitted(self, event: Input.Submitted) -> None:
        """Use the answer, or say why it cannot be used."""
        try:
            self.dismiss(site_answer(self.values(), needs_latitude=self.needs_latitude))
        except InputError as exc:
            self.query_one("#site-error", PlainStatic).update(str(exc))

    def action_cancel(self) -> None:
        """Back to the plan screen."""
        self.dismiss(None)
