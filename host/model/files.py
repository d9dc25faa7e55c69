"""Reading the TOML files every layer loads (models, motions, configurations): one place that
turns a missing, unreadable, binary or malformed file into the caller's one-line error."""

from __future__ import annotations

import tomllib
from pathlib import Path


def read_toml(path: str | Path, error: type[Exception], label: str | None = None) -> dict:
    """The parsed TOML of `path`, or `error` with one line naming the file (`label`, default
    the path) and what is wrong. FileNotFoundError passes through for callers that explain
    it (a name that is neither a file nor a built-in)."""
    label = label or str(path)
    try:
        with open(path, "rb") as f:
            data = f.read()
        # an editor's UTF-8 byte-order mark is not TOML, but it is not the author's mistake either
        return tomllib.loads(data.removeprefix(b"\xef\xbb\xbf").decode("utf-8"))
    except FileNotFoundError:
        raise
    except IsADirectoryError:
        raise error(f"{label}: is a folder, not a TOML file") from None
    except OSError as err:
        raise error(f"{label}: cannot read ({err.strerror or err})") from None
    except UnicodeDecodeError:
        raise error(f"{label}: not a text file (TOML is UTF-8 text)") from None
    except tomllib.TOMLDecodeError as err:
        raise error(f"{label}: not valid TOML ({err})") from None


def string_key(table: dict, key: str, default: str, error: type[Exception], where: str, empty: bool = True) -> str:
    """table[key], which must be a string (`default` when absent): `error` with one line naming
    `where` and the key for another type (`name = false`, `description = []`), or for an empty
    string unless `empty`."""
    value = table.get(key, default)
    if not isinstance(value, str) or not (empty or value):
        kind = "a string" if empty else "a non-empty string"
        raise error(f"{where}: '{key}' must be {kind}, got {value!r}"[:300])
    return value


BUILTIN_DIR = Path(__file__).parent / "builtin"


def builtin_models() -> dict[str, Path]:
    """Built-in model names and their files."""
    return {p.stem: p for p in sorted(BUILTIN_DIR.glob("*.toml"))}
