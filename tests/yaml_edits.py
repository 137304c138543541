"""Edits of parsed YAML data at dotted paths, for the malformed-file tests.

A path like ``cameras.2.K`` walks mappings by key and lists by index.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

Edit = Callable[[dict[str, Any]], None]


def _walk(data: Any, path: str) -> tuple[Any, int | str]:
    *parents, last = path.split(".")
    node = data
    for p in parents:
        node = node[int(p)] if p.isdigit() else node[p]
    return node, int(last) if last.isdigit() else last


def set_at(path: str, value: Any) -> Edit:
    """An edit that sets ``path`` to ``value``."""

    def edit(data: dict[str, Any]) -> None:
        node, key = _walk(data, path)
        node[key] = value

    return edit


def delete_at(path: str) -> Edit:
    """An edit that removes ``path``."""

    def edit(data: dict[str, Any]) -> None:
        node, key = _walk(data, path)
        del node[key]

    return edit
