"""Errors a user can act on.

Anything raised as `UserError` reaches the user as one line on stderr and exit
status 1, never as a traceback (see `laneprint.app.cli`).
"""

from __future__ import annotations

import re
from typing import Callable, Mapping, Optional


class UserError(Exception):
    """A problem with the user's input or workspace, explained in one line."""


class SettingError(UserError):
    """A setting, or a combination of settings, with a value the library refuses.

    The message names each setting by its field name (`episodes must be >= 1`); a negated one as
    `held_back=False`. `template` holds a `{0}`, `{1}`, ... per setting of `settings` (a name, or
    (name, value) for a setting named with its value), so that a command line can say its own
    flags instead (`as_flags`: `--episodes`, `--no-held-back`) without the library knowing them.
    """

    def __init__(self, template: str, *settings: str | tuple[str, bool]) -> None:
        self.template = template
        self.settings = [s if isinstance(s, tuple) else (s, None) for s in settings]
        super().__init__(self.text(lambda name, value: name if value is None else f"{name}={value}"))

    def text(self, say: Callable[[str, Optional[bool]], str]) -> str:
        """The message with each setting said by `say(name, value)`."""
        said = [say(name, value) for name, value in self.settings]
        return re.sub(r"\{(\d+)\}", lambda m: said[int(m[1])] if int(m[1]) < len(said) else m[0], self.template)

    def as_flags(self, flags: Optional[Mapping[str, str]] = None) -> str:
        """The message with command-line flags for the settings: `flags[name]`, else `--name-with-dashes`;
        a setting named with False as its `--no-` flag."""

        def say(name: str, value: Optional[bool]) -> str:
            flag = (flags or {}).get(name) or "--" + name.replace("_", "-")
            return f"--no-{flag[2:]}" if value is False else flag

        return self.text(say)
