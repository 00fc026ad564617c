"""Atomic file writes, for files a crash must not leave half written: the content goes to
``<path>.tmp<pid>`` in the same folder, which then replaces the target (:func:`os.replace`).

Examples:
  >>> import os, tempfile
  >>> path = os.path.join(tempfile.mkdtemp(), "a.txt")
  >>> write_text(path, "one")
  >>> open(path).read(), os.listdir(os.path.dirname(path))
  ('one', ['a.txt'])
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator


@contextlib.contextmanager
def atomic_path(
    path: str | os.PathLike, *, durable: bool = False, suffix: str = ""
) -> Iterator[str]:
    """A temporary path to write, which replaces ``path`` on leaving the block (``durable``:
    ``fsync`` first; ``suffix`` ends the name). Writers that add an extension (``np.savez``)
    need an open file instead."""
    path = os.fspath(path)
    tmp = f"{path}.tmp{os.getpid()}{suffix}"
    try:
        yield tmp
        if durable:
            with open(tmp, "rb") as f:
                os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.remove(tmp)
        raise


def write_atomic(path: str | os.PathLike, write: Callable[[str], object]) -> None:
    """``write(tmp)`` writes the file at ``tmp``, which then replaces ``path``."""
    with atomic_path(path) as tmp:
        write(tmp)


def write_text(path: str | os.PathLike, text: str, *, durable: bool = False) -> None:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_path`)."""
    with atomic_path(path, durable=durable) as tmp:
        with open(tmp, "w") as f:
            f.write(text)
