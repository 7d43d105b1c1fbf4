"""What the stage records hold, shown generically: each stage's settings (``params``) and every
other key of its record as a details table, and every stage's ``warnings``.

Nothing here names a stage's keys, so what a stage records tomorrow (a selection rule and its
knobs, a check's outcome, an anchor's mismatch) shows without a change here.
"""

import html

__all__ = ["record_rows", "stage_warnings", "flatten", "format_value", "STANDARD_KEYS", "settings_used"]

#: record keys shown elsewhere (the stages table) or not meant for reading; ``timings`` (where a
#: stage's seconds went, for benchmarks) are wall-clock traces like ``seconds``, and ``memory``
#: (the budget, a share of the memory free at the time) a trace of the machine's state
STANDARD_KEYS = ("params", "version", "status", "finished", "seconds", "timings", "memory", "inputs", "outputs",
                 "warnings")
_MAX_ITEMS = 12


def format_value(value):
    """A short plain-text rendering: numbers to 4 significant digits, long lists summarised."""
    if isinstance(value, bool) or value is None:
        return str(value)
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, (list, tuple)):
        if len(value) > 8 and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
            return f"{len(value)} values, {min(value):.4g} .. {max(value):.4g}"
        if len(value) > 8:
            return f"{len(value)} items: " + ", ".join(format_value(v) for v in value[:4]) + ", ..."
        return "[" + ", ".join(format_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {format_value(v)}" for k, v in value.items()) + "}" if value else "{}"
    return str(value)


def flatten(data, prefix=""):
    """[(dotted key, value)] of nested dicts; a dict of more than 12 entries (one per frame,
    say) is one row that names a few."""
    rows = []
    for key, value in data.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict) and value and len(value) <= _MAX_ITEMS:
            rows += flatten(value, f"{name}.")
        elif isinstance(value, dict) and value:
            rows.append((name, f"{len(value)} entries: " + ", ".join(map(str, list(value)[:4])) + ", ..."))
        else:
            rows.append((name, value))
    return rows


#: a sphere mask stored at import (pipeline.core.paths.SPHERE_MASK), which calibrate uses unasked
_STORED_SPHERE_MASK = "calibration/sphere_mask.png"


def settings_used(name, record):
    """A stage's settings as it used them: its ``params``, with what it took without an option
    named (a sphere mask stored at import, the transfer ``--gamma auto`` chose from the data),
    so that settings shown are the settings used."""
    params = dict((record or {}).get("params") or {})
    if name == "calibrate" and params.get("sphere_mask") is None \
            and _STORED_SPHERE_MASK in ((record or {}).get("inputs") or {}):
        params["sphere_mask"] = f"{_STORED_SPHERE_MASK} (stored at import)"
        params.pop("sphere_mask_sha256", None)
    decided = (record or {}).get("transfer_decision")
    if name == "decode" and params.get("gamma") == "auto" and decided:
        params["gamma"] = f"auto ({decided['transfer']}{', a guess' if decided.get('guess') else ', from the data'})"
    return params


def record_rows(record):
    """Rows [(kind, key, value)] (HTML-escaped) of a stage record: its settings, then the rest."""
    rows = [("setting", html.escape(k), html.escape(format_value(v)))
            for k, v in flatten(record.get("params") or {}) if k != "stages"]
    extra = {k: v for k, v in record.items() if k not in STANDARD_KEYS}
    rows += [("recorded", html.escape(k), html.escape(format_value(v))) for k, v in flatten(extra)]
    outputs = record.get("outputs") or []
    if outputs:
        rows.append(("recorded", "outputs", html.escape(format_value(list(outputs)))))
    return rows


def stage_warnings(session, stages):
    """[(stage, text)] of every stage record's ``warnings``, in stage order."""
    found = []
    for name in stages:
        record = session.stage(name) or {}
        found += [(name, str(w)) for w in record.get("warnings") or []]
    return found
