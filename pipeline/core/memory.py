"""The memory a stage may use: a budget (``--memory``), the memory available, and a refusal
in one line before a stage that would not fit starts (rather than the kernel's OOM killer).

Stages estimate their peak from the session's size (:func:`pipeline.photometric.stage.normals_memory`,
:func:`pipeline.integrate.stage.integrate_memory`) and compare it with :func:`budget_bytes`;
docs/big-captures.md has the measurements behind the estimates. Within the budget a stage runs
as it is; over it, it runs another way when it has one (the normals stage solves tiles from a
memory-mapped stack) or refuses. The budget is ``--memory``, by default a share of the memory
available when the stage starts (``MemAvailable``: free memory plus what the kernel can
reclaim): the stage's own (the normals stage's :data:`pipeline.settings.normals.MEMORY_SHARE`)
or :data:`DEFAULT_SHARE`.
"""

import os
import re

from .errors import InputError, StageError

__all__ = ["available_bytes", "budget_bytes", "check_budget", "format_gb", "DEFAULT_SHARE", "BASE_BYTES"]

#: the default budget's share of the available memory: the rest for the page cache and the
#: other processes of a shared machine
DEFAULT_SHARE = 0.8
#: the process before the stage holds any image: Python, numpy, OpenImageIO, numba, scipy
BASE_BYTES = 300 * 2 ** 20
_UNITS = {"": 1, "B": 1, "K": 2 ** 10, "M": 2 ** 20, "G": 2 ** 30, "T": 2 ** 40}


def available_bytes():
    """Memory the system can give a new allocation now (bytes): ``MemAvailable`` from
    /proc/meminfo, else free physical pages; the smaller of that and a cgroup's limit left."""
    found = None
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    found = int(line.split()[1]) * 1024
                    break
    except OSError:
        pass
    if found is None:
        try:
            found = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            found = 1 << 62   # nothing to go by: no budget rather than a wrong one
    try:   # a container's limit (cgroup v2) is the tighter bound when there is one
        with open("/sys/fs/cgroup/memory.max") as limit, open("/sys/fs/cgroup/memory.current") as used:
            text = limit.read().strip()
            if text != "max":
                found = min(found, max(0, int(text) - int(used.read().strip())))
    except (OSError, ValueError):
        pass
    return found


def budget_bytes(memory=None, share=DEFAULT_SHARE):
    """The budget in bytes for ``memory``: None (``share`` of the available memory: a stage's
    default, :data:`DEFAULT_SHARE` unless it declares its own), a number of bytes, or text:
    ``8G``, ``8GB``, ``1500M``, ``60%`` (of the available memory).

    Raises InputError for text it cannot read or a budget of nothing.
    """
    if memory is None:
        return int(share * available_bytes())
    if isinstance(memory, (int, float)):
        value = float(memory)
    else:
        match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*(%|[KMGT]?)(i?B)?\s*", str(memory), re.IGNORECASE)
        if not match:
            raise InputError(f"--memory: cannot read {memory!r}; give bytes, 8G, 1500M or a share such as 60%")
        number, unit = float(match.group(1)), match.group(2).upper()
        value = number / 100 * available_bytes() if unit == "%" else number * _UNITS[unit]
    if value <= 0:
        raise InputError(f"--memory: the budget must be more than nothing, got {memory!r}")
    return int(value)


def format_gb(size):
    """Bytes as '1.23 GB' (GiB, as ``free -g`` counts)."""
    return f"{size / 2 ** 30:.2f} GB"


def check_budget(where, needs, budget, helps):
    """Refuse a run that needs more than the budget: StageError with one line naming ``where``
    (the session and stage), what it ``needs`` (bytes), the budget and the memory available,
    and what ``helps``.
    """
    if needs > budget:
        raise StageError(f"{where}: needs about {format_gb(needs)} of memory, the budget is {format_gb(budget)} "
                         f"({format_gb(available_bytes())} available); {helps}")
