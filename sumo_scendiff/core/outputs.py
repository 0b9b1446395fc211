"""One output directory, one owner: a process claims a directory before it writes there.

    with claim(out) as owner:                 # OutputBusy if another live process holds ``out``
        clean_stale(out)                      # .partial-* left by processes that died
        tmp = partial_path(os.path.join(out, "scene_000"))   # scene_000.partial-<pid>
        ...write into tmp...
        publish(tmp, os.path.join(out, "scene_000"))

The claim is an ``fcntl.flock`` on ``DIR/.lock`` (which holds the owner's pid, for the message a
second process gets). The kernel drops a flock when its process dies, SIGKILL included, so a
killed run never blocks the next one; the file itself is removed when the claim ends normally.
Work in progress goes under a name unique to the writing process, so no process ever removes or
renames what another one is still writing; only the owner of the directory cleans up the
``.partial`` names of processes that no longer run.
"""
from __future__ import annotations

import contextlib
import errno
import fcntl
import itertools
import os
import re
import shutil
import time

LOCK = ".lock"
RACE_TRIES = 100      # tries to create and lock a directory other processes create or remove meanwhile
# a file system that takes no more: full, over quota, a file too large, mounted read-only
_FULL = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS})
_PARTIAL = re.compile(r"^(?P<final>.+)\.partial(?:-(?P<pid>\d+))?$")


class OutputError(Exception):
    """An output directory that cannot be used (one line: the directory and the problem)."""


class OutputBusy(OutputError):
    """Another live process owns the output directory."""


class Claim:
    def __init__(self, directory: str, fd: int, created: bool):
        self.directory, self._fd, self.created = directory, fd, created

    @property
    def lock_path(self) -> str:
        return os.path.join(self.directory, LOCK)

    def rename(self, target: str) -> None:
        """Give the claimed directory its final name, still holding the claim (``target`` must
        not exist, or be an empty directory)."""
        os.replace(self.directory, target)
        self.directory = target

    def release(self) -> None:
        if self._fd is None:
            return
        with contextlib.suppress(FileNotFoundError):
            os.remove(self.lock_path)    # before unlocking: see _lock on the retry
        os.close(self._fd)
        self._fd = None
        if self.created:                 # nothing was written: leave nothing behind
            with contextlib.suppress(OSError):
                os.rmdir(self.directory)


def _holder(path: str, wait: float = 2.0) -> str:
    # The owner writes its pid just after it takes the lock: a process that finds the lock taken
    # in between waits a moment for the pid rather than naming nobody.
    deadline = time.monotonic() + wait
    while True:
        try:
            with open(path) as f:
                pid = f.read().strip()
        except OSError:
            pid = ""
        if pid.isdigit():
            return f"process {pid}"
        if time.monotonic() > deadline:
            return "another process"
        time.sleep(0.01)


def _lock(directory: str) -> Claim:
    created = False
    path = os.path.join(directory, LOCK)
    for attempt in itertools.count():
        try:
            if not os.path.isdir(directory):
                os.makedirs(directory)
                created = True
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except (FileExistsError, FileNotFoundError) as e:
            # made by a process that got there first, or removed by an owner that just released it:
            # try again; a race ends within a few tries, a path that cannot hold a folder does not
            if os.path.exists(directory) and not os.path.isdir(directory):
                raise OutputError(f"{final_name(directory)}: exists and is not a directory") from None
            if attempt >= RACE_TRIES:
                raise OutputError(f"{final_name(directory)}: cannot be created ({e.strerror or e})") from None
            continue
        except OSError as e:
            raise OutputError(f"{final_name(directory)}: not writable ({e.strerror or e})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            os.close(fd)
            if e.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise OutputError(f"{final_name(directory)}: cannot lock ({e.strerror or e})") from None
            raise OutputBusy(f"{directory}: in use by {_holder(path)}, which writes there now "
                             f"(wait for it to end or choose another output directory)") from None
        # An owner removes the lock file before unlocking it: the file this process locked may
        # be one that is no longer in the directory, and then the claim is not a claim.
        try:
            same = os.path.samestat(os.fstat(fd), os.stat(path))
        except FileNotFoundError:
            same = False
        if same:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
            return Claim(directory, fd, created)
        os.close(fd)


@contextlib.contextmanager
def claim(directory: str):
    """Own ``directory`` (created if missing) for the ``with`` block; raises :class:`OutputBusy`
    naming the directory and the owner's pid if a live process holds it, :class:`OutputError` if
    it cannot be created or written. A directory this call created and nobody wrote into is
    removed again at the end."""
    owner = _lock(directory)
    try:
        yield owner
    except OSError as e:
        refused = write_refused(e, owner.directory)
        if refused is None:
            raise
        raise refused from None
    finally:
        owner.release()


def write_refused(e: OSError, directory: str) -> OutputError | None:
    """A write the file system refused inside ``directory`` (full, read-only, over quota, not
    permitted, failed) as the one-line :class:`OutputError` naming the directory (its final name, not the
    ``.partial`` one); None for any other error (a bug, or an input that cannot be read)."""
    inside = bool(e.filename) and os.path.abspath(str(e.filename)).startswith(os.path.abspath(directory) + os.sep)
    if e.errno not in _FULL and not (e.errno in (errno.EACCES, errno.EPERM, errno.EIO) and inside):
        return None
    where = directory if inside or not e.filename else os.path.dirname(os.path.abspath(str(e.filename)))
    return OutputError(f"{final_name(where)}: cannot write there ({e.strerror or e})")


def final_name(path: str) -> str:
    """``path`` with each ``.partial`` folder named by its final name: what the user asked for."""
    parts = path.split(os.sep)
    return os.sep.join(m.group("final") if (m := _PARTIAL.match(p)) else p for p in parts)


def partial_path(final: str) -> str:
    """The name this process writes ``final`` under until it is complete."""
    return f"{final}.partial-{os.getpid()}"


def publish(partial: str, final: str, replace: bool = False) -> str:
    """Rename a completed ``partial`` to ``final``; an existing ``final`` directory is replaced
    only with ``replace`` (otherwise the rename fails as the OS decides)."""
    if replace and os.path.isdir(final) and os.path.isdir(partial):
        shutil.rmtree(final)
    os.replace(partial, final)
    return final


def _alive(pid: int) -> bool:
    """The process runs (a zombie, dead and not yet reaped, does not)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rpartition(")")[2].split()[0] not in ("Z", "X")
    except FileNotFoundError:       # it ended in between, or there is no /proc (not Linux)
        return not os.path.isdir("/proc")
    except (OSError, IndexError):
        return True


def clean_stale(directory: str, finals=None) -> list[str]:
    """Remove the ``.partial`` / ``.partial-<pid>`` entries of ``directory`` whose writer no longer
    runs (call it only as the directory's owner); ``finals``: only the partials of these final
    names (for a directory that also holds other people's files). Returns the removed names."""
    removed = []
    for name in sorted(os.listdir(directory)):
        m = _PARTIAL.match(name)
        if not m or (finals is not None and m["final"] not in finals):
            continue
        if m["pid"] is not None and (int(m["pid"]) == os.getpid() or _alive(int(m["pid"]))):
            continue
        path = os.path.join(directory, name)
        if os.path.isdir(path) and not os.path.islink(path):
            shutil.rmtree(path, ignore_errors=True)
        else:
            with contextlib.suppress(FileNotFoundError):
                os.remove(path)
        removed.append(name)
    return removed


__all__ = ["LOCK", "Claim", "OutputBusy", "OutputError", "claim", "clean_stale", "partial_path", "publish"]
