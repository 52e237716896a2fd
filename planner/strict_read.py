"""Reading the text files a user gives the tool, strictly.

Two slips that ordinary readers let through, and that once sent a drone to the wrong place:

* **A duplicated key.** YAML (1.1 and 1.2) and JSON (RFC 8259, section 4) leave a mapping
  with two equal keys undefined, and PyYAML and Python's ``json`` keep the last one
  silently: a copy-pasted ``g3:`` under ``regions:`` replaced the first ``g3``.
  :func:`load_yaml` and :func:`load_json` refuse it, naming the key and both lines
  (:class:`DuplicateKeyError`).
* **A file that is not text.** A KMZ (a zip archive, as Google Earth exports it), an image,
  a file in another encoding, a directory: :func:`read_text` raises :class:`NotTextError`
  (or ``OSError`` for what the system refuses) instead of a ``UnicodeDecodeError``.

The callers turn these into their own one-line errors (``<file>: <where>: <problem>``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import yaml

from planner.errors import PlannerError

__all__ = ["DuplicateKeyError", "NotTextError", "load_json", "load_yaml", "read_text"]

#: The file signatures (leading bytes) of the binary formats a user is likely to give by
#: mistake, and what to call them.
_SIGNATURES: tuple[tuple[bytes, str], ...] = (
    (b"PK\x03\x04", "a zip archive (a KMZ or XLSX file?)"),
    (b"\x89PNG", "a PNG image"),
    (b"\xff\xd8\xff", "a JPEG image"),
    (b"%PDF", "a PDF document"),
    (b"\x1f\x8b", "a gzip archive"),
    (b"II*\x00", "a TIFF image"),
    (b"MM\x00*", "a TIFF image"),
    (b"\xfd7zXZ", "an xz archive"),
)


class NotTextError(PlannerError, ValueError):
    """The file is not UTF-8 text; ``str(err)`` says what it looks like instead."""


class DuplicateKeyError(PlannerError, ValueError):
    """A mapping has the same key twice.

    Attributes:
        key: the key as written.
        first, second: 1-based ``(line, column)`` of its two occurrences (``(0, 0)``: not
            known).
        mapping_path: the key path of the mapping that holds it (``regions``,
            ``vehicles[1]``; ``""`` for the top level or when not known).
    """

    def __init__(
        self,
        key: str,
        first: tuple[int, int],
        second: tuple[int, int],
        mapping_path: str = "",
    ) -> None:
        self.key = key
        self.first = first
        self.second = second
        self.mapping_path = mapping_path
        if not (first[0] and second[0]):
            where = ""
        elif first[0] != second[0]:
            where = f" (lines {first[0]} and {second[0]})"
        else:
            where = f" (line {first[0]}, columns {first[1]} and {second[1]})"
        super().__init__(
            f"duplicate key {key!r}{where}: the second would silently replace the first"
        )


def read_text(path: Path) -> str:
    """The file's text, decoded as UTF-8 (a leading byte-order mark is dropped).

    Raises:
        OSError: it cannot be read (missing, a directory, no permission).
        NotTextError: it is binary or not UTF-8; the message names the format where its
            leading bytes tell it, else the first byte that is not UTF-8 text.
    """
    if path.is_dir():
        raise IsADirectoryError(21, "Is a directory", str(path))
    raw = path.read_bytes()
    for magic, what in _SIGNATURES:
        if raw.startswith(magic):
            raise NotTextError(f"{what}, not text")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise NotTextError(f"not UTF-8 text (byte {exc.start} is 0x{raw[exc.start]:02x})") from None
    nul = text.find("\x00")
    if nul >= 0:
        raise NotTextError(f"a binary file, not text (a NUL byte at offset {nul})")
    return text


# ------------------------------------------------------------------------------------ YAML

_BASE_LOADER: Any = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class _UniqueKeyLoader(_BASE_LOADER):
    """PyYAML's safe loader (libyaml's parser where installed) refusing duplicate keys.

    Keys brought in by a merge (``<<: *anchor``) may be overridden, as YAML's merge-key
    convention intends; only keys written twice in one mapping are refused.
    """

    def construct_mapping(self, node: Any, deep: bool = False) -> Any:
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, tuple[int, int]] = {}
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    first = seen.get(key)
                except TypeError:  # an unhashable key: the base loader says so
                    continue
                mark = key_node.start_mark
                here = (mark.line + 1, mark.column + 1)
                if first is not None:
                    raise DuplicateKeyError(str(key), first, here)
                seen[key] = here
        return super().construct_mapping(node, deep=deep)


def _path_to(node: Any, target: tuple[int, int], path: str = "") -> str | None:
    """The key path of the mapping whose key starts at ``target`` (line, column), or None."""
    if isinstance(node, yaml.MappingNode):
        for key_node, value_node in node.value:
            mark = key_node.start_mark
            if (mark.line + 1, mark.column + 1) == target:
                return path
            sub = f"{path}.{key_node.value}" if path else str(key_node.value)
            found = _path_to(value_node, target, sub)
            if found is not None:
                return found
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            found = _path_to(item, target, f"{path}[{i}]")
            if found is not None:
                return found
    return None


def load_yaml(text: str) -> Any:
    """``yaml.safe_load(text)``, refusing a key written twice in one mapping.

    Raises:
        DuplicateKeyError: naming the key, both lines and the mapping's key path.
        yaml.YAMLError: the text is not YAML.
    """
    loader = _UniqueKeyLoader(text)  # a safe loader: no Python tags, no object construction
    try:
        return loader.get_single_data()
    except DuplicateKeyError as exc:
        # Only now, on the way out, find which mapping holds it (the composed node tree).
        root = yaml.compose(text, Loader=_BASE_LOADER)
        path = _path_to(root, exc.second) or ""
        raise DuplicateKeyError(exc.key, exc.first, exc.second, path) from None
    finally:
        loader.dispose()


# ------------------------------------------------------------------------------------ JSON


def _unique_pairs(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in pairs:
        if k in out:
            raise DuplicateKeyError(k, (0, 0), (0, 0))
        out[k] = v
    return out


def load_json(text: str) -> Any:
    """``json.loads(text)``, refusing a key written twice in one object.

    The fast path is ``json``'s own scanner; only when it meets a duplicate is the text read
    again (as YAML, of which JSON is nearly a subset) to find the two lines.

    Raises:
        DuplicateKeyError: naming the key and (where found) both lines.
        json.JSONDecodeError: the text is not JSON.
    """
    try:
        return json.loads(text, object_pairs_hook=_unique_pairs)
    except DuplicateKeyError as exc:
        try:
            load_yaml(text)
        except DuplicateKeyError as located:
            if located.key == exc.key:
                raise located from None
        except (yaml.YAMLError, RecursionError):
            pass
        raise
