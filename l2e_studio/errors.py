"""The one exception type for bad user input."""

from __future__ import annotations

from pathlib import Path


class InputError(ValueError):
    """A file or folder the user gave us cannot be used.

    ``str(err)`` is a single line of the form ``"<path>: <problem>"`` so that the CLI can print
    it as is and the app can show it next to the scene it belongs to.
    """

    def __init__(self, path: str | Path | None, problem: str) -> None:
        self.path = None if path is None else Path(path)
        self.problem = " ".join(str(problem).split())
        super().__init__(self.problem if path is None else f"{path}: {self.problem}")
