"""YAML of settings files (mappings, a bag's `metadata.yaml`), read with bounds.

Such a file is small and has no use for anchors and aliases, while nested aliases let a 1 KB
file expand to gigabytes (a "billion laughs"). So a file over `MAX_YAML_BYTES` is refused, and
an alias stops the reading with a `yaml.YAMLError` before anything grows.
"""

from __future__ import annotations

from typing import Any

import yaml

#: A settings file larger than this is no settings file [bytes].
MAX_YAML_BYTES = 1024 * 1024


class _NoAliasLoader(yaml.SafeLoader):
    """`yaml.SafeLoader` that refuses aliases (`*name`) where they would be expanded."""

    def compose_node(self, parent: Any, index: Any) -> Any:  # noqa: D102 - PyYAML's hook
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise yaml.composer.ComposerError(
                None, None, "aliases (*name) are not allowed in this file", event.start_mark
            )
        return super().compose_node(parent, index)


def load(text: str) -> Any:
    """The document of `text`; `yaml.YAMLError` when it is too large, not YAML, or uses an alias."""
    if len(text) > MAX_YAML_BYTES:
        raise yaml.YAMLError(f"larger than {MAX_YAML_BYTES // 1024} KB, not a settings file")
    return yaml.load(text, Loader=_NoAliasLoader)  # noqa: S506 - a SafeLoader subclass
