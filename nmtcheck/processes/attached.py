"""What a process reconstructed, kept with the input's model: the rules see only the model,
and each rule group's reconstruction (boot processes, SYNC, PDO streams, EMCYs) is built
once per input by the engine and read by its rules and the reports through this."""

from __future__ import annotations

from typing import Any, Generic, TypeVar

T = TypeVar("T")


class Attached(Generic[T]):
    """One kind of reconstruction, stored on the model under its own attribute."""

    def __init__(self, name: str) -> None:
        self._attr = f"_nmtcheck_{name}"

    def attach(self, model: Any, analysis: T) -> None:
        """Keep the analysis with the model, for the rules (which see only the model)."""
        setattr(model, self._attr, analysis)

    def of(self, model: Any) -> T | None:
        """The analysis kept with the model; None where the stage did not run."""
        found: T | None = getattr(model, self._attr, None)
        return found
