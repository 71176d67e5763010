"""An ordered, named vocabulary that can be extended: :class:`Registry`."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from typing import Generic, TypeVar

from canimucal.errors import ModelError

T = TypeVar("T")


class Registry(Mapping[str, T], Generic[T]):
    """Entries by name, in the order they were registered; read-only as a mapping.

    ``what`` names one entry in messages ("plan", "effect"). ``check(entry, registry)``
    runs before an entry joins and raises :class:`~canimucal.errors.ModelError` when it
    clashes with the others (a device code or a key used twice). Readers look entries up at
    call time, so an entry registered later (a test, a plug-in) is seen everywhere.
    """

    def __init__(
        self,
        what: str,
        name_of: Callable[[T], str],
        check: Callable[[T, Registry[T]], None] | None = None,
    ) -> None:
        self.what = what
        self._name_of = name_of
        self._check = check
        self._entries: dict[str, T] = {}

    def __getitem__(self, name: str) -> T:
        return self._entries[name]

    def __iter__(self) -> Iterator[str]:
        return iter(tuple(self._entries))

    def __len__(self) -> int:
        return len(self._entries)

    def __repr__(self) -> str:
        return f"Registry({self.what}: {', '.join(self._entries)})"

    def lookup(self, name: str) -> T:
        """Return the entry ``name``, or a ModelError that lists the names there are."""
        try:
            return self._entries[name]
        except KeyError:
            raise ModelError(f"unknown {self.what} {name!r}; one of {', '.join(self)}") from None

    def register(self, entry: T) -> T:
        """Add ``entry`` (its name must be new) and return it."""
        name = self._name_of(entry)
        if name in self._entries:
            raise ModelError(f"{self.what} {name!r} is already registered")
        if self._check is not None:
            self._check(entry, self)
        self._entries[name] = entry
        return entry

    def unregister(self, name: str) -> T:
        """Remove the entry ``name`` and return it."""
        self.lookup(name)
        return self._entries.pop(name)

    @contextmanager
    def added(self, entry: T) -> Iterator[T]:
        """Register ``entry`` for the ``with`` block only (tests, a session's own entries)."""
        self.register(entry)
        try:
            yield entry
        finally:
            self._entries.pop(self._name_of(entry), None)
