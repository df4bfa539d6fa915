"""The console's working directory: where the calibration wizard writes its files.

By default a per-user data folder, ``$XDG_DATA_HOME/beamrelay/console`` (``XDG_DATA_HOME``
unset or relative: ``~/.local/share``), created when first used; never the repository or
the scenario's folder. A path the operator types that is relative is taken relative to it.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

from planner.errors import InputError


def default_workdir(env: Mapping[str, str] | None = None) -> Path:
    """``$XDG_DATA_HOME/beamrelay/console``, or ``~/.local/share/beamrelay/console`` when
    ``XDG_DATA_HOME`` is unset, empty or relative (the XDG rule)."""
    env = os.environ if env is None else env
    base = env.get("XDG_DATA_HOME", "")
    root = Path(base) if base and os.path.isabs(base) else Path.home() / ".local" / "share"
    return root / "beamrelay" / "console"


def ensure_dir(path: Path, field: str) -> Path:
    """``path`` as an absolute, existing, writable directory (created with its parents if
    missing); InputError naming ``field`` otherwise."""
    path = Path(path).expanduser().absolute()
    if path.exists() and not path.is_dir():
        raise InputError(f"{path} is a file: expected a directory", field)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create {path}: {exc.strerror}", field) from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise InputError(f"{path} is not writable", field)
    return path


def output_path(workdir: Path, text: str, field: str, suffixes: tuple[str, ...]) -> Path:
    """The file the operator typed in ``field`` (relative: under ``workdir``), its folder
    created; InputError when it is empty, a directory, has another suffix or cannot be
    written."""
    path = input_path(workdir, text, field)
    if path.is_dir():
        raise InputError(f"{path} is a directory: expected a file", field)
    if path.suffix not in suffixes:
        raise InputError(f"{path.name}: expected a {' or '.join(suffixes)} file", field)
    ensure_dir(path.parent, field)
    if path.exists() and not os.access(path, os.W_OK):
        raise InputError(f"{path} is not writable", field)
    return path


def input_path(workdir: Path, text: str, field: str) -> Path:
    """The path typed in ``field``, absolute (relative: under ``workdir``)."""
    if not text.strip():
        raise InputError("empty: expected a file name", field)
    path = Path(text.strip()).expanduser()
    return path if path.is_absolute() else Path(workdir) / path
