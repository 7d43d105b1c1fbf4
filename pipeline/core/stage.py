"""The stage protocol: what every stage of a session (decode, calibrate, normals, integrate,
report) is to the runner, the Dask scheduler and the command line.

A stage is a :class:`Stage`: a ``name``, the :class:`pipeline.core.options.Options` it takes
(``Options``; None for a stage with nothing to set), the session inputs it ``reads``, and
:meth:`Stage.run`, which returns an :class:`Outcome` whether it ran or found its record
current. Its record (``session.yaml``'s ``stages.<name>``) holds its parameters, input and
output hashes, and :meth:`Stage.replay` turns the recorded parameters back into the options
that reproduce them, so that ``psrig run`` keeps what a stage was last run with. Staleness,
hashes and the record itself are :class:`pipeline.core.session.Session`'s
(``stage_is_current``, ``record_stage``), the same for every stage.

The stages themselves live beside their topic (``pipeline/decode/stage.py``,
``calibration/stage.py``, ``pipeline/photometric/stage.py``, ``pipeline/integrate/stage.py``,
``pipeline/report/stage.py``); :data:`pipeline.runner.RUNNERS` lists them in running order.
"""

from dataclasses import dataclass, field

__all__ = ["Stage", "Outcome"]


@dataclass
class Outcome:
    """What one stage did.

    Attributes
    ----------
    name : str
    ran : bool
        False when the stage's record was current and nothing was written.
    record : dict or None
        The stage record after the run (None for a stage that keeps none).
    note : str
        What a user should know of the run (or why the stage was skipped).
    warnings : list of str
        The run's warnings (empty when it did not run: they are in the old record).
    seconds : float
        Wall time.
    """

    name: str
    ran: bool
    record: dict = None
    note: str = ""
    warnings: list = field(default_factory=list)
    seconds: float = 0.0

    @property
    def outputs(self):
        """The files the record lists (relative to the session)."""
        return list(((self.record or {}).get("outputs") or {}))

    def describe(self):
        """The stage's one line: what it did, its note and its warnings."""
        if self.ran:
            line = f"{self.name}: ran in {self.seconds:.1f} s" + (f"; {self.note}" if self.note else "")
        else:
            line = f"{self.name}: up to date" + (f" ({self.note})" if self.note else "")
        return line + "".join(f"; warning: {w}" for w in self.warnings)


class Stage:
    """Base of the stages (see the module docstring).

    Subclasses set ``name``, ``Options`` and ``reads`` and implement :meth:`work`, which
    returns ``(ran, note)``: whether it wrote anything (False when its record was current) and
    its note. :meth:`run` times it and reads its record.
    """

    name = ""
    Options = None
    #: the session files (or kinds of file) the stage reads, for the docs and the design
    reads = ()

    def check(self, options):
        """``options`` (a mapping) checked against :attr:`Options`: an unknown name lists the
        known ones."""
        return self.Options.check(options, where=self.name) if self.Options is not None else dict(options)

    def run(self, session, options=None, *, force=False, jobs=None):
        """Run the stage on an open session (whose lock the caller holds) with ``options``;
        returns an :class:`Outcome`."""
        import time

        start = time.perf_counter()
        ran, note = self.work(session, self.check(options or {}), force=force, jobs=jobs)
        record = session.stage(self.name)
        warnings = [str(w) for w in (record or {}).get("warnings") or []] if ran else []
        return Outcome(self.name, bool(ran), record, note or "", warnings, time.perf_counter() - start)

    def work(self, session, options, *, force, jobs):
        """Do the stage's work; returns ``(ran, note)``."""
        raise NotImplementedError

    def replay(self, record):
        """Keyword options that reproduce a stage record's parameters ({} without a record)."""
        params = dict((record or {}).get("params") or {})
        return self.Options.check({k: v for k, v in params.items() if k in self.Options.specs()}) \
            if self.Options is not None and params else {}

    def merge(self, recorded, given):
        """The options to run with: ``recorded`` (:meth:`replay`) replaced key by key by ``given``."""
        return {**recorded, **given}

    def __call__(self, session, options, force, jobs):
        """The runner's call: :meth:`run`."""
        return self.run(session, options, force=force, jobs=jobs)
