"""Atomic file writes: the one way the library writes a file that a crash must not leave
half written (metrics, data sets, checkpoint manifests, sweep cells, cached references).

The content goes to a temporary file next to the target (``<path>.tmp<pid>``: the same
folder, so the same file system, and a name no other process uses), which then replaces
the target with :func:`os.replace`, atomic on POSIX and Windows. A reader sees the old
file or the new one, never a part. On an error the temporary file is removed and the
target is untouched.

Examples:
  >>> import os, tempfile
  >>> path = os.path.join(tempfile.mkdtemp(), "a.txt")
  >>> write_text(path, "one")
  >>> with atomic_path(path) as tmp:
  ...     with open(tmp, "w") as f:
  ...         _ = f.write("two")
  >>> open(path).read(), os.listdir(os.path.dirname(path))
  ('two', ['a.txt'])
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator


@contextlib.contextmanager
def atomic_path(
    path: str | os.PathLike, *, durable: bool = False, suffix: str = ""
) -> Iterator[str]:
    """A temporary path to write; on leaving the block it replaces ``path``.

    Args:
      path: the file to write.
      durable: also flush the temporary file to the disk (``fsync``) before the rename, so
        that the new content survives a power cut, not only a crash of the process.
      suffix: appended to the temporary name, for writers that pick the format from the
        file's extension (``".mp4"`` for ffmpeg).

    Yields:
      The temporary path (``<path>.tmp<pid><suffix>``). Writers that add an extension to a
      name (``np.savez``) must be given an open file instead.
    """
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
