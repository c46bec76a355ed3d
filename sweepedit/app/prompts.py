"""What the app's controllers (sweepedit.app.file_control, sweepedit.app.fit_control)
need from the window to tell and ask the user. The window is it; the controllers look its
methods up at each call, so tests that replace the window's dialogs reach them too."""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from sweepedit.app.autosave import Recovery


class UserPrompts(Protocol):
    """Errors, status lines and questions, in the user's words."""

    def report_error(self, title: str, message: str) -> None: ...
    def show_status(self, message: str, timeout_ms: int = 6000) -> None: ...
    def ask_save_changes(self) -> str: ...
    def ask_keep_primitives(self, shape_name: str) -> str: ...
    def ask_recover(self, recovery: Recovery) -> bool: ...
