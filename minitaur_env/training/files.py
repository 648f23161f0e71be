"""Writing files so that a kill leaves either the old file or the new one, never a torn one."""

from __future__ import annotations

import contextlib
import os
import pickle
import re
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import yaml

from minitaur_env.training import UsageError


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """A temporary path beside ``path`` that replaces it only if the block succeeds."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    handle, temp_name = tempfile.mkstemp(
        prefix=f".{target.stem}.", suffix=target.suffix, dir=target.parent
    )
    os.close(handle)
    temp = Path(temp_name)
    try:
        yield temp
        # mkstemp makes the file private (0600); give it the usual permissions.
        umask = os.umask(0)
        os.umask(umask)
        temp.chmod(0o666 & ~umask)
        os.replace(temp, target)
    finally:
        temp.unlink(missing_ok=True)


def refuse_to_replace(path: Path, replace: bool, flag: str) -> None:
    """A published folder (a shipped policy, a Hub folder) is replaced only when asked:
    the one there may be the only copy of an agent and its provenance."""
    if path.exists() and not replace:
        raise UsageError(f"{flag}: {path} is already there; add --replace to replace it")


@contextlib.contextmanager
def replaced_folder(path: str | os.PathLike[str]) -> Iterator[Path]:
    """A new folder, named as ``path``, that replaces ``path`` only if the block succeeds.

    What is published (a shipped policy, a Hub folder) is written aside and swapped in
    whole, so that a failure part-way leaves the old folder as it was, never a mix of old
    and new files. The old folder waits beside the new one until the swap is done.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    staging_root = Path(tempfile.mkdtemp(prefix=f".{target.name}.new-", dir=target.parent))
    staged = staging_root / target.name
    staged.mkdir()
    try:
        yield staged
        aside = staging_root / f"{target.name}.old"
        had_one = target.exists()
        if had_one:
            os.replace(target, aside)
        try:
            os.replace(staged, target)
        except OSError:
            if had_one:
                os.replace(aside, target)
            raise
    finally:
        shutil.rmtree(staging_root, ignore_errors=True)


class _Loader(yaml.SafeLoader):
    """YAML 1.1's safe loader, reading ``1e-4`` as the number it means: its resolver wants a
    dot (``1.0e-4``), and every config file and flag written the other way read a string."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(
        r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
        |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
        |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
        |[-+]?\.(?:inf|Inf|INF)
        |\.(?:nan|NaN|NAN))$""",
        re.X,
    ),
    list("-+0123456789."),
)


def parse_yaml(text: str) -> Any:
    """The one YAML reader of the package (configs, search spaces, flags, provenance)."""
    return yaml.load(text, Loader=_Loader)


def read_yaml(path: str | os.PathLike[str], what: str = "YAML file") -> Any:
    """The file's YAML, or a UsageError naming ``what`` could not be read or parsed."""
    try:
        return parse_yaml(Path(path).read_text())
    except OSError as error:
        raise UsageError(f"cannot read {what} {path}: {error.strerror or error}") from error
    except yaml.YAMLError as error:
        raise UsageError(f"{what} {path} is not valid YAML: {error}") from error


def read_lines(path: Path) -> list[str]:
    """The file's lines, each with its line ending as written: a log rewritten from these
    keeps SB3's CRLF monitor lines byte for byte, and a line torn after its ``\\r`` still
    reads as unfinished."""
    with path.open(newline="") as handle:
        return handle.read().splitlines(True)


def write_text(path: Path, text: str) -> None:
    with atomic_path(path) as temporary:
        temporary.write_text(text, newline="")


def write_yaml(path: Path, content: dict[str, Any], sort_keys: bool = True) -> None:
    write_text(path, yaml.safe_dump(content, sort_keys=sort_keys))


def load_pickle(path: Path) -> Any:
    with path.open("rb") as handle:
        return pickle.load(handle)


def ensure_writable(folder: Path) -> None:
    """Create ``folder`` if needed and prove it is writable, or raise a UsageError."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        # A uniquely named probe: runs started together must not delete each other's.
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as error:
        raise UsageError(f"cannot write to {folder}: {error.strerror or error}") from error


@contextlib.contextmanager
def exclusive(lock_file: Path, what: str) -> Iterator[None]:
    """Hold an exclusive lock on ``lock_file`` for the block, or raise a UsageError naming
    ``what`` if another process holds it. The OS releases it when its process dies, so a
    ``kill -9`` never leaves it stuck. (Where ``fcntl`` is missing, Windows, no lock.)"""
    try:
        import fcntl
    except ImportError:
        yield
        return
    with open(lock_file, "a") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise UsageError(f"{what} is in use by another process") from None
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)
