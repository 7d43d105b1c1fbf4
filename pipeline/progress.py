"""Progress bars for long work (frames, pixels, iterations), on tqdm, written to stderr."""

from tqdm.auto import tqdm

__all__ = ["progress"]


def progress(iterable=None, *, total=None, desc=None, unit="it", disable=None):
    """A tqdm progress bar on stderr; silent when stderr is not a terminal unless forced."""
    return tqdm(iterable, total=total, desc=desc, unit=unit, disable=disable, leave=False,
                dynamic_ncols=True)
