"""Write files so that a crash or error mid-write never destroys the previous version.

Every file kgnav writes (models, HTML pages, plots, JSON) goes through :func:`atomic_open`: the
bytes go to a temporary file beside the target, which replaces the target in one rename once
they are on disk. On top of the rename:

* **permissions** — a replaced file keeps its mode (and, where the user may set it, its group);
  a new file gets ``0666`` less the umask, as ``open()`` would give it (``mkstemp`` alone would
  leave ``0600``);
* **symbolic links** — writing to a link writes the file it points to (atomically, beside that
  file) and keeps the link; a dangling link or a loop is an error, nothing is created;
* **temporary files** are named ``.<target>.<pid>-<host>.<random>.tmp`` and removed on any
  failure. One that a killed writer left behind names its writer, so :func:`stale_temp` can tell
  whether that writer is gone (:class:`kgnav.memory.store.ModelStore` removes such files).
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import re
import socket
import stat
import tempfile
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from typing import IO

TEMP_SUFFIX = ".tmp"
_HOST = hashlib.blake2s(socket.gethostname().encode(), digest_size=4).hexdigest()
_TEMP_NAME = re.compile(r"\.(?P<target>.+)\.(?P<pid>[0-9]+)-(?P<host>[0-9a-f]{8})\.[^.]+\.tmp")
_umask_lock = threading.Lock()


def current_umask() -> int:
    """The process's umask, read without changing it where the system allows."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    with _umask_lock:  # os.umask can only be read by setting it
        mask = os.umask(0o022)
        os.umask(mask)
    return mask


def resolve_target(path: str | os.PathLike[str]) -> str:
    """The file a write to ``path`` replaces: ``path`` itself, or where its symbolic link points.

    Raises ``OSError`` for a dangling link or a loop of links.
    """
    path = os.path.abspath(os.fspath(path))
    if not os.path.islink(path):
        return path
    real = os.path.realpath(path)
    try:
        os.stat(path)
    except FileNotFoundError:
        raise FileNotFoundError(
            errno.ENOENT, f"dangling symbolic link (to {os.readlink(path)})", path
        ) from None
    return real


@contextlib.contextmanager
def atomic_open(
    path: str | os.PathLike[str], mode: str = "wb", *, encoding: str | None = None
) -> Iterator[IO]:
    """Open a temporary file beside ``path``; on success it replaces ``path`` in one rename.

    On any exception the temporary file is removed and ``path`` is left as it was. Text modes
    default to UTF-8. See the module documentation for permissions and symbolic links.

    >>> import pathlib, tempfile
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "a.txt"
    >>> with atomic_open(p, "w") as fh:
    ...     _ = fh.write("hello")
    >>> p.read_text()
    'hello'
    >>> oct(p.stat().st_mode & 0o777) == oct(0o666 & ~current_umask())
    True
    """
    target = resolve_target(path)
    directory, base = os.path.split(target)
    os.makedirs(directory, exist_ok=True)
    try:
        old = os.stat(target)
    except FileNotFoundError:
        old = None
    if old is not None and not stat.S_ISREG(old.st_mode):
        raise IsADirectoryError(errno.EISDIR, "exists and is not a regular file", target)
    if "b" not in mode and encoding is None:
        encoding = "utf-8"
    fd, tmp = tempfile.mkstemp(
        prefix=f".{base}.{os.getpid()}-{_HOST}.", suffix=TEMP_SUFFIX, dir=directory
    )
    try:
        if old is None:
            os.fchmod(fd, 0o666 & ~current_umask())
        else:
            os.fchmod(fd, stat.S_IMODE(old.st_mode))
            if old.st_gid != os.fstat(fd).st_gid:
                with contextlib.suppress(OSError):  # allowed only for the user's own groups
                    os.fchown(fd, -1, old.st_gid)
        with os.fdopen(fd, mode, encoding=encoding) as fh:
            fd = -1  # the file object owns it now
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        if fd >= 0:
            os.close(fd)
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


@dataclass(frozen=True)
class TempFile:
    """What the name of a temporary file left by :func:`atomic_open` says about its writer."""

    target: str  # the file name it was to replace
    pid: int
    host: str  # a hash of the writer's host name

    @property
    def this_host(self) -> bool:
        return self.host == _HOST


def temp_file_info(name: str) -> TempFile | None:
    """Parse a temporary file's name; ``None`` if :func:`atomic_open` did not make the name."""
    m = _TEMP_NAME.fullmatch(name)
    if m is None:
        return None
    return TempFile(m["target"], int(m["pid"]), m["host"])


def pid_alive(pid: int) -> bool:
    """Whether a process with this id exists on this host."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, another user's
        return True
    except OverflowError:
        return False
    return True


def stale_temp(name: str) -> bool:
    """True for a temporary file of :func:`atomic_open` whose writer, on this host, is gone.

    Files of writers on other hosts (a shared file system) and files named otherwise are never
    called stale: nothing here can tell whether their writer still runs.
    """
    info = temp_file_info(name)
    return info is not None and info.this_host and not pid_alive(info.pid)
