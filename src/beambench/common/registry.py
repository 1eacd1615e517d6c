"""A registry of named things (scenes, beam builders, streams, figures, rigs), in the manner of dm_control's
``suite``: each module registers its item once under a name, and the code that uses them looks them up by name
or walks them in registration order.

A name registered twice is a :class:`DuplicateName` (a ``ValueError``); a name looked up but never registered is
an :class:`UnknownName` (a ``KeyError``) whose message lists the registered names.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from typing import TypeVar

T = TypeVar("T")


class DuplicateName(ValueError):
    """A second item for a name the registry has."""


class UnknownName(KeyError):
    """A name the registry does not have; the message lists the ones it has."""

    def __str__(self) -> str:  # KeyError would quote the whole message
        return str(self.args[0]) if self.args else ""


class Registry(Mapping[str, T]):
    """Items by name, in registration order. ``kind`` names an item in messages ("scene", "sim stream");
    ``verb`` says how items come in ("registered", "declared"); ``missing`` what an unknown name lacks
    ("is not registered", "has no builder")."""

    def __init__(self, kind: str, *, verb: str = "registered", missing: str | None = None) -> None:
        self.kind = kind
        self.verb = verb
        self.missing = missing if missing is not None else f"is not {verb}"
        self._items: dict[str, T] = {}

    def add(self, name: str, item: T) -> T:
        """Register ``item`` as ``name``; :class:`DuplicateName` if the name has one already."""
        self.check_free(name)
        self._items[name] = item
        return item

    def check_free(self, name: str) -> None:
        """:class:`DuplicateName` if ``name`` has an item already (a decorator may check before it wraps)."""
        if name in self._items:
            raise DuplicateName(f"{self.kind} {name!r} is {self.verb} twice")

    def register(self, name: str) -> Callable[[T], T]:
        """Decorator: register the decorated object itself as ``name``."""

        def add(item: T) -> T:
            return self.add(name, item)

        return add

    def __getitem__(self, name: str) -> T:
        try:
            return self._items[name]
        except KeyError:
            raise UnknownName(self.unknown(name)) from None

    def unknown(self, name: str) -> str:
        """The message for a name this registry does not have, listing the ones it has."""
        known = f"{self.verb}: {', '.join(self._items)}" if self._items else f"no {self.kind} is {self.verb}"
        return f"{self.kind} {name!r} {self.missing} ({known})"

    def __iter__(self) -> Iterator[str]:
        return iter(self._items)

    def __len__(self) -> int:
        return len(self._items)

    def __contains__(self, name: object) -> bool:
        return name in self._items

    @contextmanager
    def restoring(self, name: str) -> Iterator[None]:
        """Whatever ``name`` is given in the ``with`` block, afterwards it answers as before (or is unknown again);
        every other name keeps what it got meanwhile (tests register a toy in a process-wide registry this way)."""
        had = name in self._items
        before = self._items.get(name)
        try:
            yield
        finally:
            if had:
                self._items[name] = before  # type: ignore[assignment]
            else:
                self._items.pop(name, None)

    @contextmanager
    def stand_in(self, name: str, item: T) -> Iterator[T]:
        """For the ``with`` block, ``item`` answers to ``name`` (in place of the registered one, or added)."""
        with self.restoring(name):
            self._items[name] = item
            yield item
