"""Session folders: layout, the ``session.yaml`` manifest (format ``psrig-session/1``), frames,
stage records and ground truth.

A session is the unit every stage reads and writes::

    SESSION/
      session.yaml   manifest
      raw/           frames as captured; never modified once written
      linear/        decoded float32 frames (<frame id>.exr) + saturation masks (<id>_sat.png)
      calibration/   lights.yaml, lights.lp, overlays
      normals/  depth/  report/
      truth/         ground truth when known (simulated or imported sessions)

Every manifest write is atomic, so a process killed at any moment leaves a valid session.
"""

import datetime as _dt
import hashlib
import re
from pathlib import Path, PurePosixPath

import yaml

from . import __version__
from .atomic import atomic_write_bytes, atomic_write_text
from .errors import ManifestError, SessionError
from .yamlio import plain

__all__ = ["Session", "FORMAT", "FRAME_KINDS", "STAGES", "file_sha256", "now_iso"]

FORMAT = "psrig-session/1"
MANIFEST = "session.yaml"
# outline: an evenly (room-)lit photo of the spheres with the rig's lights off, used only to find
# their circles; like dark and ambient frames it has no light, but nothing is subtracted with it
FRAME_KINDS = ("object", "sphere", "dark", "ambient", "target", "outline")
LIT_KINDS = ("object", "sphere", "target")
STAGES = ("decode", "calibrate", "normals", "integrate", "report")
FOLDERS = ("raw", "linear", "calibration", "normals", "depth", "report", "truth")
# libyaml's safe loader and dumper when PyYAML has them (same text, ~5x faster: a capture saves
# the manifest after every frame), else PyYAML's pure-Python safe ones.
_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)
_SHA_RE = re.compile(r"^[0-9a-f]{64}$")
_ID_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


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

    # ------------------------------------------------------------------ opening and saving
    @classmethod
    def create(cls, root, *, rig=None, camera=None, lights=None, exist_ok=False):
        """Create a session folder with an empty manifest.

        Parameters
        ----------
        root : path
            Folder to create. It may exist only if empty (or, with ``exist_ok``, if it is
            already a session, which is then opened).
        rig, camera, lights : dict, optional
            Descriptions stored under the manifest keys of the same names.
        """
        root = Path(root)
        if (root / MANIFEST).exists():
            if exist_ok:
                return cls.open(root)
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
        session.save()
        return session

    @classmethod
    def open(cls, root):
        """Open an existing session, validating its manifest."""
        root = Path(root)
        path = root / MANIFEST
        if not root.is_dir():
            raise SessionError(f"{root}: no such session folder")
        if not path.is_file():
            raise SessionError(f"{root}: not a session folder (no {MANIFEST})")
        try:
            manifest = yaml.load(path.read_text(encoding="utf-8"), Loader=_LOADER)
        except (yaml.YAMLError, UnicodeDecodeError) as exc:
            raise ManifestError(f"{path}: not valid YAML: {exc}") from None
        validate_manifest(manifest, str(path))
        return cls(root, manifest)

    def save(self):
        """Validate and atomically write ``session.yaml``."""
        validate_manifest(self.manifest, str(self.root / MANIFEST))
        text = yaml.dump(self.manifest, Dumper=_DUMPER, sort_keys=False, allow_unicode=True)
        atomic_write_text(self.root / MANIFEST, text)

    def __repr__(self):
        return f"Session({str(self.root)!r}, frames={len(self.frames())})"

    # ------------------------------------------------------------------ paths
    def path(self, rel):
        """Absolute path of a session-relative path, refusing anything outside the session."""
        check_relative(str(rel), f"{self.root / MANIFEST}: path")
        full = (self.root / rel).resolve()
        if not full.is_relative_to(self.root.resolve()):
            raise SessionError(f"{self.root}: path {rel!r} resolves outside the session folder")
        return full

    def rel(self, path):
        """Session-relative POSIX path of an absolute path inside the session."""
        return Path(path).resolve().relative_to(self.root.resolve()).as_posix()

    def linear_path(self, frame):
        """Where the decoded float32 EXR of ``frame`` (dict or id) lives."""
        return self.root / "linear" / f"{_frame_id(frame)}.exr"

    def saturation_path(self, frame):
        """Where the saturation mask PNG of ``frame`` (dict or id) lives."""
        return self.root / "linear" / f"{_frame_id(frame)}_sat.png"

    # ------------------------------------------------------------------ frames
    def frames(self, kind=None):
        """Frames of the manifest (dicts), optionally of one kind, in manifest order."""
        frames = self.manifest["frames"]
        return [f for f in frames if kind is None or f["kind"] == kind]

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
        """Raise :class:`SessionError` if the frame's file is missing or its sha256 changed."""
        path = self.path(frame["file"])
        if not path.is_file():
            raise SessionError(f"{path}: raw file of frame {frame['id']!r} is missing")
        digest = file_sha256(path)
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
        hashes = {}
        for rel in rels:
            path = self.path(rel)
            if not path.is_file():
                raise SessionError(f"{path}: input file is missing")
            hashes[rel] = file_sha256(path)
        return hashes

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
        for rel, digest in (record.get("outputs") or {}).items():
            path = self.root / rel
            if not path.is_file() or file_sha256(path) != digest:
                return False
        return True

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


def _output_hashes(session, outputs):
    if isinstance(outputs, dict):
        return {check_relative(rel, "outputs"): digest for rel, digest in outputs.items()}
    return {rel: file_sha256(session.path(rel)) for rel in outputs}


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
    seen = set()
    for i, frame in enumerate(frames):
        _validate_frame(frame, f"{where}: frames[{i}]", seen)
    for name, record in manifest["stages"].items():
        _validate_stage(record, f"{where}: stages.{name}")
    for key, rel in manifest["truth"].items():
        check_relative(rel, f"{where}: truth.{key}")


def _validate_frame(frame, where, seen):
    if not isinstance(frame, dict):
        raise ManifestError(f"{where}: must be a mapping")
    for key in ("id", "kind", "file", "sha256"):
        if key not in frame:
            raise ManifestError(f"{where}: missing key '{key}'")
    if not isinstance(frame["id"], str) or not _ID_RE.match(frame["id"]):
        raise ManifestError(f"{where}.id: {frame['id']!r} is not a valid frame id")
    if frame["id"] in seen:
        raise ManifestError(f"{where}.id: duplicate frame id {frame['id']!r}")
    seen.add(frame["id"])
    if frame["kind"] not in FRAME_KINDS:
        raise ManifestError(f"{where}.kind: {frame['kind']!r} is not one of {', '.join(FRAME_KINDS)}")
    light = frame.get("light")
    if frame["kind"] in LIT_KINDS:
        if isinstance(light, bool) or not isinstance(light, int) or light < 0:
            raise ManifestError(f"{where}.light: a {frame['kind']} frame needs a light index >= 0, got {light!r}")
    elif light is not None:
        raise ManifestError(f"{where}.light: a {frame['kind']} frame has no light, got {light!r}")
    check_relative(frame["file"], f"{where}.file")
    if not isinstance(frame["sha256"], str) or not _SHA_RE.match(frame["sha256"]):
        raise ManifestError(f"{where}.sha256: expected 64 lowercase hex digits, got {frame['sha256']!r}")


def _validate_stage(record, where):
    if not isinstance(record, dict):
        raise ManifestError(f"{where}: must be a mapping")
    for key in ("params", "inputs", "outputs"):
        if not isinstance(record.get(key, {}), dict):
            raise ManifestError(f"{where}.{key}: must be a mapping")
    for key in ("inputs", "outputs"):
        for rel, digest in (record.get(key) or {}).items():
            check_relative(rel, f"{where}.{key}")
            if not isinstance(digest, str) or not _SHA_RE.match(digest):
                raise ManifestError(f"{where}.{key}[{rel!r}]: expected a sha256, got {digest!r}")
