"""The decoder under test and its results as isolation/ reads them: the few attributes of an
adapter and of a case result it needs, as protocols (the classes live in harness/, a layer
above; isolation/ must not import them)."""

from __future__ import annotations

from enum import Enum
from typing import Protocol

from .sandbox import Limits


class Decoder(Protocol):
    """An adapter (harness/adapters.py): a command decoder, or one run in-process."""

    @property
    def name(self) -> str: ...
    @property
    def kind(self) -> str: ...  # "command" or in-process ("python")
    @property
    def limits(self) -> Limits: ...
    @property
    def inputs(self) -> list[str]: ...
    @property
    def faps_format(self) -> str: ...


class Ended(Protocol):
    """How one case's decoder process ended (a harness CaseResult)."""

    @property
    def case_id(self) -> str: ...
    @property
    def outcome(self) -> Enum: ...
    @property
    def stderr_tail(self) -> str: ...
    @property
    def exit_code(self) -> int | None: ...
    @property
    def signal(self) -> str | None: ...
    @property
    def crash_kind(self) -> str | None: ...
    @property
    def message(self) -> str: ...
