"""Session folders: layout, the ``session.yaml`` manifest (format ``psrig-session/1``), frames,
stage records and ground truth.

A session is the unit every stage reads and writes::

    SESSION/
      session.yaml   manifest
      raw/           frames as captured; never modified once written
      linear/        decoded float32 frames (<frame id>.exr) + saturation masks (<id>_sat.png);
                     an exposure bracket's exposures and their merge (<group>.exr)
      calibration/   lights.yaml, lights.lp, overlays
      normals/  depth/  report/
      truth/         ground truth when known (simulated or imported sessions)

Every manifest write is atomic, so a process killed at any moment leaves a valid session. A
command that writes a session opens it with ``writer=`` (its name): it then holds the session's
lock (:mod:`pipeline.core.lock`) until it closes it or ends, the session's folders are checked to lie
inside it, and temporary files an interrupted writer left are removed (:attr:`Session.swept`).
"""

import datetime as _dt
import hashlib
import json
import math
import os
import re
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path, PurePosixPath

import yaml

from .. import __version__
from . import lock as _lock
from .atomic import atomic_write_bytes, atomic_write_text, sweep_tree
from .brackets import FRAME_ID, check_brackets, stage_view
from .errors import ManifestError, SessionError
from .hashes import HashCache
from .paths import SCRATCH, linear_frame, saturation_frame
from .yamlio import dump_yaml, load_yaml, plain

__all__ = ["Session", "FORMAT", "FRAME_KINDS", "STAGES", "file_sha256", "now_iso"]

FORMAT = "psrig-session/1"
MANIFEST = "session.yaml"
# outline: an evenly (room-)lit photo of the spheres with the rig's lights off, used only to find
# their circles; like dark and ambient frames it has no light, but nothing is subtracted with it
FRAME_KINDS = ("object", "sphere", "dark", "ambient", "target", "outline")
LIT_KINDS = ("object", "sphere", "target")
STAGES = ("decode", "calibrate", "normals", "integrate", "report")
FOLDERS = ("raw", "linear", "calibration", "normals", "depth", "report", "truth")
#: Folders whose stale temporaries a writer sweeps when it takes the lock; raw/ is capture's own
#: (``psrig capture --resume`` sorts out what an interrupted capture left there).
SWEPT = ("", "linear", "calibration", "normals", "depth", "report", "truth")
#: Status values of a stage record ('incomplete': a decode still running, or interrupted).
STATUSES = ("ok", "partial", "failed", "incomplete")
_SHA_RE = re.compile(r"^[0-9a-f]{64}$")


def now_iso():
    """Current UTC time as an ISO-8601 string (seconds)."""
    return _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()


def file_sha256(path, chunk=1 << 20):
    """Hex sha256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(chunk), b""):
            digest.update(block)
    return digest.hexdigest()


def check_relative(rel, where):
    """Validate a manifest path: relative, POSIX, no '..', no empty parts. Returns it as str."""
    if not isinstance(rel, str) or not rel:
        raise ManifestError(f"{where}: expected a relative path, got {rel!r}")
    pure = PurePosixPath(rel)
    if pure.is_absolute() or rel.startswith(("/", "\\")) or re.match(r"^[A-Za-z]:", rel):
        raise ManifestError(f"{where}: absolute path {rel!r} is not allowed (paths are relative)")
    if ".." in pure.parts or "\\" in rel:
        raise ManifestError(f"{where}: path {rel!r} leaves the session folder")
    return rel


class Session:
    """A session folder and its manifest.

    Use :meth:`create` for a new session and :meth:`open` for an existing one. The manifest is
    a plain dict (``session.manifest``) validated on open and on every :meth:`save`.
    """

    def __init__(self, root, manifest):
        self.root = Path(root)
        self.manifest = manifest
        self.lock = None
        #: {folder: (files, bytes)} of the stale temporaries removed when the lock was taken
        self.swept = {}
        #: the files' digests, remembered against their size, times and inode (.psrig.hashes)
        self.hashes = HashCache(self.root)

    # ------------------------------------------------------------------ opening and saving
    @classmethod
    def create(cls, root, *, rig=None, camera=None, lights=None, exist_ok=False, writer=None):
        """Create a session folder with an empty manifest.

        Parameters
        ----------
        root : path
            Folder to create. It may exist only if empty (or, with ``exist_ok``, if it is
            already a session, which is then opened).
        rig, camera, lights : dict, optional
            Descriptions stored under the manifest keys of the same names.
        writer : str, optional
            The command creating it, which then holds the session's lock (see :meth:`open`).
        """
        root = Path(root)
        if (root / MANIFEST).exists():
            if exist_ok:
                return cls.open(root, writer=writer)
            raise SessionError(f"{root}: already a session (session.yaml exists)")
        if root.exists() and any(root.iterdir()):
            raise SessionError(f"{root}: folder exists and is not empty; refusing to make a session there")
        root.mkdir(parents=True, exist_ok=True)
        manifest = {
            "format": FORMAT,
            "created": now_iso(),
            "psrig_version": __version__,
            "rig": dict(rig or {}),
            "camera": dict(camera or {}),
            "lights": dict(lights or {}),
            "frames": [],
            "stages": {},
            "truth": {},
        }
        session = cls(root, manifest)
        for name in FOLDERS:
            (root / name).mkdir(exist_ok=True)
        # Written without the lock: nobody else can be writing a session that does not exist yet,
        # and the lock file comes after the manifest, so a capture killed here leaves a folder
        # that ``--resume`` recognises as stillborn.
        session._write()
        return session.acquire(writer) if writer else session

    @classmethod
    def open(cls, root, *, writer=None, wait=False, on_wait=None):
        """Open an existing session, validating its manifest.

        Parameters
        ----------
        root : path
        writer : str, optional
            The command that will write the session (``'run'``, ``'decode'``, ...). It takes the
            session's lock first (:meth:`acquire`). Without it the session is opened to read;
            its :meth:`save` then takes the lock just for the write.
        wait : bool
            With ``writer``: wait for another writer to finish instead of raising
            :class:`pipeline.core.lock.SessionLocked`; ``on_wait(line)`` is told once.
        """
        root = Path(root)
        if not root.is_dir():
            raise SessionError(f"{root}: no such session folder")
        if not (root / MANIFEST).is_file():
            raise SessionError(f"{root}: not a session folder (no {MANIFEST})")
        session = cls(root, None)
        if writer:
            return session.acquire(writer, wait=wait, on_wait=on_wait)
        session.manifest = read_manifest(root / MANIFEST)
        return session

    def acquire(self, writer, *, wait=False, on_wait=None):
        """Take the session's lock for ``writer`` (a command name), then re-read the manifest
        (another writer may have changed it), check that the session's folders lie inside it and
        sweep what interrupted writers left (:attr:`swept`). Returns self.

        Calling it again on a session that holds the lock does nothing. In a worker process
        acting under its parent's lock (:func:`pipeline.core.lock.act_under`) nothing is swept.
        """
        if self.lock is not None:
            return self
        lock = _lock.acquire(self.root, writer, wait=wait, on_wait=on_wait)
        try:
            self.manifest = read_manifest(self.root / MANIFEST)
            self.check_folders()
            if writer != "capture":  # capture --resume adopts such files itself
                self.check_unlisted_raw()
            if not lock.delegated and lock.users == 1:
                self.swept = self._sweep()
        except BaseException:
            lock.release()
            raise
        self.lock = lock
        return self

    def release(self):
        """Give up the session's lock (if this session holds it)."""
        lock, self.lock = self.lock, None
        if lock is not None:
            lock.release()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()

    def __del__(self):
        # a session dropped without release() gives its share of the lock back, like a file
        try:
            self.release()
        except Exception:  # noqa: BLE001 - interpreter shutdown: the kernel drops the lock anyway
            pass

    def check_folders(self):
        """Refuse a session whose folders are not folders inside it (a symlinked ``normals/``
        pointing elsewhere): psrig writes only inside the session folder. Checked before any
        write of a writer."""
        inside = self.root.resolve()
        for name in FOLDERS:
            folder = self.root / name
            if not (folder.exists() or folder.is_symlink()):
                continue
            resolved = folder.resolve()
            if not resolved.is_relative_to(inside):
                raise SessionError(f"{folder}: links to {resolved}, outside the session folder; "
                                   "psrig writes only inside the session (make it a real folder)")
            if not resolved.is_dir():
                raise SessionError(f"{folder}: not a folder")

    def check_unlisted_raw(self):
        """Refuse to write a session whose manifest, saved by a psrig before ``frame_count``,
        may have lost frames: files in ``raw/`` that no frame names show it. (A manifest with
        ``frame_count`` shows a cut itself; an unlisted file beside it is an interrupted capture's.)"""
        raw = self.root / "raw"
        if "frame_count" in self.manifest or not raw.is_dir() or raw.is_symlink():
            return
        named = {PurePosixPath(f["file"]).as_posix() for f in self.manifest["frames"]}
        unlisted = sorted(p.name for p in raw.iterdir()
                          if not p.name.startswith(".") and p.is_file() and f"raw/{p.name}" not in named)
        if unlisted:
            shown = ", ".join(unlisted[:3]) + (" ..." if len(unlisted) > 3 else "")
            raise ManifestError(
                f"{self.root / MANIFEST}: raw/ holds {len(unlisted)} file(s) no frame names ({shown}), and the "
                "manifest (saved by an earlier psrig, without frame_count) cannot show whether it lost frames. "
                f"A captured session: psrig capture {self.root} --resume --rig NAME adopts them; otherwise "
                "restore session.yaml from your copies, or move files that are not the session's out of raw/")

    def _sweep(self):
        """Remove the temporaries and scratch folders interrupted writers left; {folder: (files,
        bytes)}. Only the lock holder calls it: no live writer can own them."""
        swept = {}
        for name in SWEPT:
            files, size = sweep_tree(self.root / name, recursive=bool(name))
            for scratch in SCRATCH:
                if scratch.startswith(f"{name}/") and name:
                    more, more_size = sweep_tree(self.root / scratch, everything=True)
                    files, size = files + more, size + more_size
            if files:
                swept[name or "."] = (files, size)
        return swept

    def describe_swept(self, named=True):
        """One line on what :attr:`swept` removed, or ''; ``named`` False leaves the session's
        path out (for lines a caller prefixes with it)."""
        if not self.swept:
            return ""
        files = sum(f for f, _ in self.swept.values())
        size = sum(b for _, b in self.swept.values())
        where = ", ".join(f"{name}/ {f}" for name, (f, _) in self.swept.items())
        return (f"{self.root}: " * named + f"removed {files} temporary file{'s' * (files != 1)} "
                f"({size / 1e6:.1f} MB) left by an interrupted run ({where})")

    def save(self):
        """Validate and atomically write ``session.yaml`` (under the session's lock)."""
        with _lock.authorize(self.root):
            self._write()

    def _write(self):
        validate_manifest(self.manifest, str(self.root / MANIFEST))
        frames = self.manifest["frames"]
        # frame_count near the top and saved last: a manifest cut short at a line boundary
        # lost one of them (or frames: they no longer match the count) and is refused on reading
        rest = [(k, v) for k, v in self.manifest.items() if k not in ("format", "frame_count", "saved")]
        self.manifest.clear()  # in place: callers may hold the dict
        self.manifest.update([("format", FORMAT), ("frame_count", len(frames))] + rest)
        self.manifest["saved"] = now_iso()
        atomic_write_text(self.root / MANIFEST, dump_yaml(self.manifest))

    def __repr__(self):
        return f"Session({str(self.root)!r}, frames={len(self.frames())})"

    # ------------------------------------------------------------------ paths
    def path(self, rel):
        """Absolute path of a session-relative path, refusing anything outside the session."""
        check_relative(str(rel), f"{self.root / MANIFEST}: path")
        given = self.root / rel
        full = given.resolve()
        if not full.is_relative_to(self.real_root):
            raise SessionError(f"{self.root}: path {rel!r} resolves outside the session folder")
        if full != self.real_root / rel and os.path.islink(given):
            # a link to another file of the session: a writer would replace that file (a raw frame)
            raise SessionError(f"{given}: is a symbolic link to {os.readlink(given)}; a session's files "
                               "are never links (replace it by the file itself)")
        return full

    def rel(self, path):
        """Session-relative POSIX path of an absolute path inside the session."""
        return Path(path).resolve().relative_to(self.real_root).as_posix()

    @property
    def real_root(self):
        """The session folder with its symlinks resolved, once: every path check compares with
        it, and resolving it each time was a quarter of decoding a small frame."""
        if getattr(self, "_real_root", None) is None or self._real_root[0] != self.root:
            self._real_root = (self.root, self.root.resolve())
        return self._real_root[1]

    def linear_path(self, frame):
        """Where the decoded float32 EXR of ``frame`` (dict or id) lives (checked like :meth:`path`)."""
        return self.path(linear_frame(_frame_id(frame)))

    def saturation_path(self, frame):
        """Where the saturation mask PNG of ``frame`` (dict or id) lives (checked like :meth:`path`)."""
        return self.path(saturation_frame(_frame_id(frame)))

    # ------------------------------------------------------------------ frames
    def frames(self, kind=None):
        """Frames of the manifest (dicts), optionally of one kind, in manifest order."""
        frames = self.manifest["frames"]
        return [f for f in frames if kind is None or f["kind"] == kind]

    def stage_frames(self, kind=None):
        """Frames as the stages after decode read them, optionally of one kind, in manifest order.

        The exposures of an exposure bracket (frames with ``bracket: {group, ...}``) are ONE
        frame here, whose id is the group's: decode merges them into its
        :meth:`linear_path` / :meth:`saturation_path`. It carries ``kind``, ``light``,
        ``file`` (its first exposure's), ``merged_from`` (the exposures' ids) and
        ``shutters`` (:meth:`pipeline.core.brackets.BracketGroup.as_frame`). Every other frame is
        its manifest dict, as :meth:`frames` gives it.
        """
        return [f for f in stage_view(self.manifest["frames"]) if kind is None or f["kind"] == kind]

    def frame(self, frame_id):
        """The frame dict with this id."""
        for frame in self.manifest["frames"]:
            if frame["id"] == frame_id:
                return frame
        raise SessionError(f"{self.root}: no frame {frame_id!r} in the manifest")

    def has_frame(self, frame_id):
        return any(f["id"] == frame_id for f in self.manifest["frames"])

    def add_frame(self, kind, data=None, *, light=None, suffix=".dng", frame_id=None, source=None,
                  save=True, **extra):
        """Store a new frame in ``raw/`` and record it in the manifest.

        Parameters
        ----------
        kind : {'object', 'sphere', 'dark', 'ambient', 'target', 'outline'}
        data : bytes, optional
            The frame's bytes, exactly as the camera delivered them. Give either ``data`` or
            ``source`` (a file to copy).
        light : int, optional
            0-based light index; required for object, sphere and target frames.
        suffix : str
            File extension in ``raw/`` (ignored when ``source`` is given: its extension is kept).
        frame_id : str, optional
            Defaults to ``{kind}_{light:03d}`` for lit frames and ``{kind}_{n:03d}`` otherwise.
        extra
            Further keys stored in the frame entry (exposure, capture time, ...).

        The raw file is written atomically and never overwritten: an existing file of the
        same name is an error. Returns the new frame dict.
        """
        if kind not in FRAME_KINDS:
            raise SessionError(f"unknown frame kind {kind!r}; expected one of {', '.join(FRAME_KINDS)}")
        if (data is None) == (source is None):
            raise SessionError("add_frame needs exactly one of data or source")
        if source is not None:
            source = Path(source)
            suffix = source.suffix
            data = source.read_bytes()
        frame_id = frame_id or self._next_id(kind, light)
        if self.has_frame(frame_id):
            raise SessionError(f"{self.root}: frame {frame_id!r} is already in the manifest")
        rel = f"raw/{frame_id}{suffix.lower()}"
        target = self.path(rel)
        if target.exists():
            raise SessionError(f"{target}: a raw file of that name exists already; captures are never overwritten")
        atomic_write_bytes(target, data)
        frame = {"id": frame_id, "kind": kind, "light": None if light is None else int(light),
                 "file": rel, "sha256": hashlib.sha256(data).hexdigest()}
        if source is not None:
            frame["source"] = source.name
        frame.update(extra)
        self.manifest["frames"].append(frame)
        if save:
            self.save()
        return frame

    def adopt_frame(self, kind, rel, *, light=None, frame_id=None, save=True, **extra):
        """Record a raw file that is already in ``raw/`` but missing from the manifest.

        This happens when a capture was killed between the atomic write of the frame and the
        manifest update: the file is complete (it was renamed into place) and must be neither
        lost nor captured twice. The caller checks the file parses before adopting it.
        """
        if kind not in FRAME_KINDS:
            raise SessionError(f"unknown frame kind {kind!r}; expected one of {', '.join(FRAME_KINDS)}")
        rel = check_relative(rel, "adopt_frame")
        if not rel.startswith("raw/"):
            raise SessionError(f"{rel}: only files in raw/ can be adopted as frames")
        path = self.path(rel)
        if not path.is_file():
            raise SessionError(f"{path}: no such raw file to adopt")
        if any(f["file"] == rel for f in self.manifest["frames"]):
            raise SessionError(f"{path}: already recorded in the manifest")
        frame_id = frame_id or self._next_id(kind, light)
        if self.has_frame(frame_id):
            raise SessionError(f"{self.root}: frame {frame_id!r} is already in the manifest")
        frame = {"id": frame_id, "kind": kind, "light": None if light is None else int(light),
                 "file": rel, "sha256": file_sha256(path), "adopted": True}
        frame.update(extra)
        self.manifest["frames"].append(frame)
        if save:
            self.save()
        return frame

    def _next_id(self, kind, light):
        if kind in LIT_KINDS and light is not None:
            return f"{kind}_{int(light):03d}"
        n = len(self.frames(kind))
        while self.has_frame(f"{kind}_{n:03d}"):
            n += 1
        return f"{kind}_{n:03d}"

    def verify_frame(self, frame):
        """Raise :class:`SessionError` if the frame's file is missing or its sha256 changed
        (a file unchanged since it was last hashed is not read again: :attr:`hashes`; the caller
        saves them)."""
        path = self.path(frame["file"])
        if not path.is_file():
            raise SessionError(f"{path}: raw file of frame {frame['id']!r} is missing")
        digest = self._sha256(frame["file"], path)
        if digest != frame["sha256"]:
            raise SessionError(f"{path}: frame {frame['id']!r} does not match its sha256 in the manifest "
                               "(the file changed after capture)")
        return digest

    # ------------------------------------------------------------------ stages
    def stage(self, name):
        """The stage record (dict) or None."""
        return self.manifest["stages"].get(name)

    def hash_inputs(self, rels):
        """{relative path: sha256} for session files (missing files raise SessionError)."""
        paths = []
        for rel in rels:
            path = self.path(rel)
            if not path.is_file():
                raise SessionError(f"{path}: input file is missing")
            paths.append(path)
        if len(paths) < 4:
            found = {rel: self._sha256(rel, path) for rel, path in zip(rels, paths)}
        else:
            # hashlib releases the GIL on large blocks: a stage of a hundred frames hashes them
            # on every core; map keeps the order of ``rels``
            with ThreadPoolExecutor(min(8, os.cpu_count() or 1), thread_name_prefix="psrig-hash") as pool:
                found = dict(zip(rels, pool.map(self._sha256, rels, paths)))
        self.hashes.save()
        return found

    def _sha256(self, rel, path):
        """The sha256 of ``path`` (session-relative ``rel``), remembered in :attr:`hashes`."""
        return self.hashes.digest(rel, path, file_sha256)

    def manifest_input(self, label, frames, keys):
        """A stage input {``session.yaml#<label>``: sha256} covering manifest fields the stage reads.

        ``frames`` (dicts) and ``keys`` (the fields read, e.g. ``('id', 'light')``) are hashed in
        order, so that editing any of them in ``session.yaml`` (swapping two frames' ``light``,
        pointing a ``file:`` elsewhere) makes the stage's record stale like a changed file.
        """
        rows = [[frame.get(key) for key in keys] for frame in frames]
        text = json.dumps({"keys": list(keys), "frames": rows}, sort_keys=True, default=str)
        return {f"{MANIFEST}#{label}": hashlib.sha256(text.encode()).hexdigest()}

    def stage_is_current(self, name, params, inputs):
        """True when stage ``name`` ran with these params and these input hashes.

        ``inputs`` is {relative path: sha256}. Outputs recorded by the stage must still exist
        with the recorded hashes.
        """
        record = self.stage(name)
        if not record or record.get("status", "ok") != "ok":
            return False
        if record.get("params") != plain(params) or record.get("inputs") != inputs:
            return False
        current = all((self.root / rel).is_file() and self._sha256(rel, self.root / rel) == digest
                      for rel, digest in (record.get("outputs") or {}).items())
        self.hashes.save()
        return current

    def record_stage(self, name, params, inputs, outputs, *, status="ok", seconds=None, save=True, **extra):
        """Record that stage ``name`` ran.

        Parameters
        ----------
        params : dict
            Every parameter that changes the outputs (plain YAML types).
        inputs : dict
            {relative path: sha256} of the files read.
        outputs : iterable of str, or dict
            Relative paths written; their hashes are stored so later edits are noticed. A dict
            {relative path: sha256} gives hashes the stage already computed.
        status : str
            'ok', or 'partial' / 'failed' (then ``failed`` in ``extra`` says which and why).
        """
        record = {
            "params": plain(params),
            "version": __version__,
            "inputs": dict(inputs),
            "outputs": _output_hashes(self, outputs),
            "status": status,
            "finished": now_iso(),
        }
        if seconds is not None:
            record["seconds"] = round(float(seconds), 3)
        record.update(plain(extra))
        self.manifest["stages"][name] = record
        if save:
            self.save()
        return record

    def invalidate_stages(self, first):
        """Forget the record of stage ``first`` and of every stage after it."""
        names = STAGES[STAGES.index(first):] if first in STAGES else (first,)
        for name in names:
            self.manifest["stages"].pop(name, None)
        self.save()

    # ------------------------------------------------------------------ ground truth
    def truth(self, key):
        """Absolute path of a ground-truth item ('normals', 'mask', 'lights', 'depth', ...) or None."""
        rel = self.manifest.get("truth", {}).get(key)
        return None if rel is None else self.path(rel)

    def set_truth(self, key, rel, save=True):
        self.manifest.setdefault("truth", {})[key] = check_relative(rel, f"truth.{key}")
        if save:
            self.save()


def read_manifest(path):
    """The validated manifest (dict) of ``session.yaml`` at ``path``; ManifestError naming it."""
    try:
        manifest = load_yaml(Path(path).read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ManifestError(f"{path}: not valid YAML: {exc}") from None
    except OSError as exc:
        raise ManifestError(f"{path}: cannot read the manifest ({exc.strerror})") from None
    validate_manifest(manifest, str(path))
    _check_complete(manifest, str(path))
    return manifest


def _validate_subtracted(subtracted, where):
    """``subtracted`` of a decode record: {kind, frames, by_kind: {lit kind: {kind, frames}}}."""
    if subtracted is None:
        return
    entries = [(where, subtracted)] + [(f"{where}.by_kind.{k}", v)
                                       for k, v in (subtracted.get("by_kind") or {}).items()]
    if not isinstance(subtracted.get("by_kind") or {}, dict):
        raise ManifestError(f"{where}.by_kind: expected a mapping, got {subtracted['by_kind']!r}")
    for place, entry in entries:
        if not isinstance(entry, dict):
            raise ManifestError(f"{place}: expected a mapping, got {entry!r}")
        kind, frames = entry.get("kind"), entry.get("frames") or []
        if kind is not None and not isinstance(kind, str):
            raise ManifestError(f"{place}.kind: expected a frame kind, got {kind!r}")
        if not isinstance(frames, list) or not all(isinstance(f, str) for f in frames):
            raise ManifestError(f"{place}.frames: expected a list of frame ids, got {frames!r}")


def _output_hashes(session, outputs):
    if isinstance(outputs, dict):
        return {check_relative(rel, "outputs"): digest for rel, digest in outputs.items()}
    found = {rel: session._sha256(rel, session.path(rel)) for rel in outputs}
    session.hashes.save()
    return found


def _frame_id(frame):
    return frame["id"] if isinstance(frame, dict) else str(frame)


# ---------------------------------------------------------------------- validation
def validate_manifest(manifest, where):
    """Raise :class:`ManifestError` naming the first bad key of a manifest."""
    if not isinstance(manifest, dict):
        raise ManifestError(f"{where}: the manifest must be a mapping, got {type(manifest).__name__}")
    if manifest.get("format") != FORMAT:
        raise ManifestError(f"{where}: key 'format' must be {FORMAT!r}, got {manifest.get('format')!r}")
    for key in ("rig", "camera", "lights", "stages", "truth"):
        if not isinstance(manifest.setdefault(key, {}), dict):
            raise ManifestError(f"{where}: key '{key}' must be a mapping")
    frames = manifest.setdefault("frames", [])
    if not isinstance(frames, list):
        raise ManifestError(f"{where}: key 'frames' must be a list")
    seen, files = set(), {}
    for i, frame in enumerate(frames):
        _validate_frame(frame, f"{where}: frames[{i}]", seen)
        other = files.setdefault(frame["file"], frame["id"])
        if other != frame["id"]:
            raise ManifestError(f"{where}: frames[{i}].file: frames {other!r} and {frame['id']!r} both "
                                f"name {frame['file']!r}; every frame has a raw file of its own")
    check_brackets(frames, where)
    for name, record in manifest["stages"].items():
        _validate_stage(record, f"{where}: stages.{name}")
    for key, rel in manifest["truth"].items():
        check_relative(rel, f"{where}: truth.{key}")
    object_mask = manifest["lights"].get("object_mask")
    if object_mask is not None:
        check_relative(object_mask, f"{where}: lights.object_mask")


def _check_complete(manifest, where):
    """Refuse a manifest read from disk that was cut short: saved by this version (it has
    ``frame_count``) but without its last key ``saved``, or listing other than ``frame_count``
    frames."""
    count = manifest.get("frame_count")
    if count is None:
        return  # saved by an earlier version, which did not count
    if isinstance(count, bool) or not isinstance(count, int) or count < 0:
        raise ManifestError(f"{where}: key 'frame_count' must be a number of frames, got {count!r}")
    if "saved" not in manifest:
        raise ManifestError(f"{where}: the manifest ends before its last key 'saved': the file was cut "
                            "short (psrig keeps no copy): restore session.yaml from your copies")
    saved = manifest["saved"]
    if not (isinstance(saved, _dt.date) or (isinstance(saved, str) and saved.strip())):
        raise ManifestError(f"{where}: key 'saved' must be the time of the save (text), got {manifest['saved']!r}")
    listed = len(manifest["frames"])
    if listed != count:
        cause = ("it lost frames (cut short?): restore session.yaml from your copies (psrig keeps none); "
                 "a captured session can be completed after setting frame_count by psrig capture --resume, "
                 "which adopts the frames left in raw/; or, " if listed < count else "")
        raise ManifestError(f"{where}: lists {listed} frames but was saved with {count} (frame_count): "
                            f"{cause}if the frames were changed by hand on purpose, set frame_count: {listed}")


def _validate_frame(frame, where, seen):
    if not isinstance(frame, dict):
        raise ManifestError(f"{where}: must be a mapping")
    for key in ("id", "kind", "file", "sha256"):
        if key not in frame:
            raise ManifestError(f"{where}: missing key '{key}'")
    if not isinstance(frame["id"], str) or not FRAME_ID.match(frame["id"]):
        raise ManifestError(f"{where}.id: {frame['id']!r} is not a valid frame id")
    if frame["id"] in seen:
        raise ManifestError(f"{where}.id: duplicate frame id {frame['id']!r}")
    seen.add(frame["id"])
    if frame["kind"] not in FRAME_KINDS:
        raise ManifestError(f"{where}.kind: {frame['kind']!r} is not one of {', '.join(FRAME_KINDS)}")
    light = frame.get("light")
    if frame["kind"] in LIT_KINDS:
        if isinstance(light, bool) or not isinstance(light, int) or light < 0:
            raise ManifestError(f"{where}.light: {frame['kind']} frames need a light index >= 0, got {light!r}")
    elif light is not None:
        raise ManifestError(f"{where}.light: a {frame['kind']} frame has no light, got {light!r}")
    check_relative(frame["file"], f"{where}.file")
    if not isinstance(frame["sha256"], str) or not _SHA_RE.match(frame["sha256"]):
        raise ManifestError(f"{where}.sha256: expected 64 lowercase hex digits, got {frame['sha256']!r}")
    applies = frame.get("applies_to")
    if applies is not None and (not isinstance(applies, list) or any(k not in LIT_KINDS for k in applies)):
        raise ManifestError(f"{where}.applies_to: expected a list of lit kinds ({', '.join(LIT_KINDS)}), "
                            f"got {applies!r}")
    if frame.get("source") is not None and not isinstance(frame["source"], str):
        raise ManifestError(f"{where}.source: expected a file name, got {frame['source']!r}")


#: Types of the stage-record fields psrig reads (a field may be absent): {key: (types, what)}
_RECORD_FIELDS = {
    "params": (dict, "a mapping"), "inputs": (dict, "a mapping"), "outputs": (dict, "a mapping"),
    "status": (str, "one of " + ", ".join(STATUSES)), "version": (str, "a version"),
    "finished": (str, "a date"), "seconds": ((int, float), "a number of seconds"),
    "failed": (dict, "a mapping of frame ids to reasons"), "frames": (dict, "a mapping of frame ids"),
    "subtracted": (dict, "a mapping"), "frames_not_raw": (list, "a list of frame ids"),
    "warnings": (list, "a list"), "status_counts": (dict, "a mapping of counts"),
    "pixels": (int, "a number of pixels"), "flagged": (dict, "a mapping of lights to reasons"),
    "merged": (dict, "a mapping of bracket groups"),
}


def _validate_stage(record, where):
    if not isinstance(record, dict):
        raise ManifestError(f"{where}: must be a mapping")
    for key, (types, what) in _RECORD_FIELDS.items():
        value = record.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, types)):
            raise ManifestError(f"{where}.{key}: expected {what}, got {value!r}")
    if record.get("status", "ok") not in STATUSES:
        raise ManifestError(f"{where}.status: expected one of {', '.join(STATUSES)}, got {record['status']!r}")
    if not math.isfinite(record.get("seconds") or 0):
        raise ManifestError(f"{where}.seconds: expected a number of seconds, got {record['seconds']!r}")
    for key in ("frames", "failed"):
        for frame_id, value in (record.get(key) or {}).items():
            if not isinstance(value, dict if key == "frames" else str):
                raise ManifestError(f"{where}.{key}.{frame_id}: expected "
                                    f"{'a mapping' if key == 'frames' else 'a reason'}, got {value!r}")
    _validate_subtracted(record.get("subtracted"), f"{where}.subtracted")
    for key in ("inputs", "outputs"):
        for rel, digest in (record.get(key) or {}).items():
            check_relative(rel, f"{where}.{key}")
            if not isinstance(digest, str) or not _SHA_RE.match(digest):
                raise ManifestError(f"{where}.{key}[{rel!r}]: expected a sha256, got {digest!r}")
