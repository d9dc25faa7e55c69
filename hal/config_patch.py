"""Changes to a user's robot configuration, written the way a careful person would: the file's
comments, order and layout kept (tomlkit), the change shown before it is written, and never without
a confirmation. A built-in configuration is part of the installed package: its patched copy goes to
a file of the user's.

    patch = ConfigPatch.of(config)                   # the file behind a loaded configuration
    patch.set_joint("r_elbow_flexion", zero_offset=2.113, direction=-1)
    print("\n".join(patch.changes()))                # what would change, one line per value
    patch.write()                                    # to patch.target
    patch.offer(confirm)                             # or: show the change, ask confirm(question), write

The file is written in place of the old one only once the patched text loads as a configuration;
it keeps the old file's permissions, a symbolic link is followed to the file it names (that file is
patched, the link stays), and anything but a regular file (a device, a folder) is refused. The
question itself is the command line's (`confirm`).
"""

from __future__ import annotations

import math
import os
import stat
import tempfile
from pathlib import Path
from typing import Callable

import tomlkit

from .config import load_config
from .errors import ConfigError


def _plain(value):
    """A TOML value as plain Python, for comparing and printing."""
    if isinstance(value, list):
        return [_plain(v) for v in value]
    return value.unwrap() if hasattr(value, "unwrap") else value


def _shown(value) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_shown(v) for v in value) + "]"
    return str(value)


class ConfigPatch:
    """Edits to one configuration file, applied to its text as TOML (comments kept)."""

    def __init__(self, source: Path, target: Path):
        self.source, self.target = Path(source), Path(target)
        self.document = tomlkit.parse(self.source.read_text())
        self._changes: list[tuple[str, str, object, object]] = []     # (where, key, old, new)

    @classmethod
    def of(cls, config, target: str | Path | None = None) -> "ConfigPatch":
        """The patch of a loaded configuration's file; a built-in one is copied to `target`
        (default ./<name>.toml), since the package's own file is not the user's to change."""
        if config.path is None:
            raise ConfigError(f"'{config.name}' was not loaded from a file: nothing to patch")
        if target is None:
            target = Path(f"{config.name}.toml") if config.builtin else config.path
            if config.builtin and target.exists():
                # the change would be shown against the built-in, then replace the user's own file
                raise ConfigError(f"{target} exists and '{config.name}' named the built-in configuration: give "
                                  f"--config ./{target} to patch your file, or --write FILE for a new copy")
        return cls(config.path, Path(target))

    @property
    def copies(self) -> bool:
        return self.source.resolve() != self.target.resolve()

    def set_joint(self, dof: str, **values) -> None:
        """Set keys of the [[joint]] table whose dof is `dof` (added at its end when absent)."""
        tables = [t for t in self.document.get("joint", []) if t.get("dof") == dof]
        if not tables:
            raise ConfigError(f"{self.source}: no [[joint]] with dof = \"{dof}\"")
        table = tables[0]
        for key, new in values.items():
            if isinstance(new, float):
                new = float(f"{new:.6g}") if math.isfinite(new) else new
            if isinstance(new, tuple):
                new = [float(f"{v:.6g}") for v in new]
            old = _plain(table.get(key)) if key in table else None
            if old == new:
                continue
            if isinstance(new, list) and isinstance(old, list) and len(old) == len(new):
                for i, value in enumerate(new):       # in place: the array's comments and layout kept
                    table[key][i] = value
            elif isinstance(new, list):
                array = tomlkit.array()
                array.extend(new)
                table[key] = array
            else:
                table[key] = new
            self._changes.append((f"joint '{dof}'", key, old, new))

    def set_table(self, name: str, **values) -> None:
        """Set keys of the top-level table [name] (added at the file's end when absent)."""
        if name not in self.document:
            self.document.add(name, tomlkit.table())
        table = self.document[name]
        for key, new in values.items():
            if isinstance(new, float):
                new = float(f"{new:.6g}") if math.isfinite(new) else new
            if isinstance(new, (list, tuple)):
                new = [float(f"{v:.6g}") for v in new]
            if isinstance(new, dict):       # a table by name (a value per dof): written inline
                new = {k: float(f"{v:.6g}") for k, v in new.items()}
            old = _plain(table.get(key)) if key in table else None
            if old == new:
                continue
            if isinstance(new, dict):
                inline = tomlkit.inline_table()
                inline.update(new)
                table[key] = inline
            else:
                table[key] = new
            self._changes.append((f"[{name}]", key, old, new))

    def changes(self) -> list[str]:
        """One line per value that changes: where, key, old -> new."""
        return [f"{where}: {key} {'(unset)' if old is None else _shown(old)} -> {_shown(new)}"
                for where, key, old, new in self._changes]

    def text(self) -> str:
        return tomlkit.dumps(self.document)

    def write(self) -> Path:
        """Write the patched text to the target (atomically: a temporary file renamed over it), after
        checking that it still loads as a configuration. A link is followed (its file is patched),
        the file's permissions are kept, and a target that is no regular file is refused."""
        text = self.text()
        real = Path(os.path.realpath(self.target))
        try:
            mode = stat.S_IMODE(real.stat().st_mode) if real.exists() else None
        except OSError as err:
            raise ConfigError(f"{self.target}: {err.strerror or err}") from None
        if real.exists() and not real.is_file():
            raise ConfigError(f"{self.target} is not a regular file: a configuration is written to a file")
        fd, tmp = tempfile.mkstemp(prefix=".servodyn-", suffix=".toml", dir=real.parent)
        try:
            with os.fdopen(fd, "w") as out:
                out.write(text)
            if mode is not None:
                os.chmod(tmp, mode)
            else:
                umask = os.umask(0)
                os.umask(umask)
                os.chmod(tmp, 0o666 & ~umask)      # a new file as any other the user makes
            load_config(tmp)           # a patch that breaks the file is refused, the file untouched
            os.replace(tmp, real)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise
        return self.target

    def offer(self, confirm: Callable[[str], bool], say: Callable = print) -> int:
        """Show the change, ask confirm(question), and write it: 0 when written (or nothing
        changes), 1 when the user declines. A write that fails raises ConfigError, naming the file;
        the file is untouched."""
        changes = self.changes()
        if not changes:
            say("the configuration already holds these values: nothing to write")
            return 0
        say(f"changes to {self.target}" + (f" (a copy of the built-in {self.source.name})" if self.copies else "") + ":")
        for line in changes:
            say(f"  {line}")
        if not confirm(f"write {self.target}?"):
            say("nothing written")
            return 1
        try:
            self.write()
        except (ConfigError, OSError) as err:
            raise ConfigError(f"{self.target}: not written: {err}") from None
        say(f"wrote {self.target}" + (f": use it with --config {self.target}" if self.copies else ""))
        return 0
