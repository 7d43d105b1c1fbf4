"""Files' sha256 remembered against what the file system says of them, so that a stage hashes an
unchanged input once.

Every stage decides whether it is up to date by its inputs' sha256 (and checks its outputs'),
which means reading every frame of a session: at 24 MP x 96 lights a ``psrig run`` on a session
already processed spent about a minute hashing 15 GB to say so. :class:`HashCache` keeps, in
the session's ``.psrig.hashes``, each file's digest with its size, modification and status-change
times (nanoseconds), inode and device. A file whose five still match is not read again: its
content cannot have changed without its status-change time (``ctime``) moving, which no tool can
set back, and a copy or a move elsewhere has another inode. A file changed within
:data:`SETTLE_SECONDS` of its hashing is not remembered (a coarse clock might not tell a change
in the same tick), nor is one that changed while it was read. The cache is a hint only: unreadable,
damaged, a link, or not writable (a read-only archive), it is ignored and every file hashed.
"""

import json
import os
import threading
import time

from .atomic import atomic_write_text
from .errors import PsrigError

__all__ = ["HASHES_FILE", "SETTLE_SECONDS", "HashCache"]

#: the cache's file in a session folder
HASHES_FILE = ".psrig.hashes"
#: a file modified less than this long before it was hashed is hashed again the next time
SETTLE_SECONDS = 2.0


def _key(stat):
    return [stat.st_size, stat.st_mtime_ns, stat.st_ctime_ns, stat.st_ino, stat.st_dev]


class HashCache:
    """The digests of files under ``root``, by relative path; ``digest(rel, path, hasher)``
    returns the remembered one when the file is unchanged, else ``hasher(path)``; ``save()``
    writes what was learnt (best effort)."""

    def __init__(self, root):
        self.path = os.path.join(str(root), HASHES_FILE)
        self._entries = None
        self._changed = False
        self._lock = threading.Lock()

    def _load(self):
        if self._entries is None:
            entries = {}
            try:
                if not os.path.islink(self.path):
                    with open(self.path, encoding="utf-8") as handle:
                        loaded = json.load(handle)
                    if isinstance(loaded, dict):
                        entries = {rel: entry for rel, entry in loaded.items()
                                   if isinstance(entry, list) and len(entry) == 6 and isinstance(entry[5], str)}
            except (OSError, ValueError):
                pass
            self._entries = entries
        return self._entries

    def digest(self, rel, path, hasher):
        """The sha256 of ``path`` (session-relative ``rel``)."""
        before = os.stat(path)
        with self._lock:
            entry = self._load().get(rel)
        if entry is not None and entry[:5] == _key(before):
            return entry[5]
        digest = hasher(path)
        after = os.stat(path)
        settled = time.time_ns() - max(after.st_mtime_ns, after.st_ctime_ns) > SETTLE_SECONDS * 1e9
        if settled and _key(after) == _key(before):
            with self._lock:
                self._entries[rel] = _key(after) + [digest]
                self._changed = True
        return digest

    def save(self):
        """Write the cache if it learnt something; a failure to write is not an error."""
        with self._lock:
            if not self._changed:
                return
            text = json.dumps(self._entries, separators=(",", ":"))
            self._changed = False
        try:
            if not os.path.islink(self.path):
                atomic_write_text(self.path, text)
        except (OSError, PsrigError):   # a read-only archive, a folder in the way: hash again next time
            pass
